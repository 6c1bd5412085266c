"""The mission asks for OFFBOARD again only while the drone lacks its setpoints (a lossy start-up),
never after any other refusal, and never past its wait."""
from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import Any

import pytest

from drone_contract.commands import NO_SETPOINTS_YET, POSITION_UNKNOWN
from drone_contract.messages import CommandResult, VehicleState
from gcs import mission

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


class _Drone:
    """What the mission reads and calls of a drone, with scripted offboard_start answers."""

    def __init__(self, answers: list[CommandResult]) -> None:
        self.id = "uav1"
        self.state = VehicleState(connected=True, armable=False)
        self.setpoints_sent = 10
        self.may_stream = True
        self.failures: list[str] = []
        self.answers = answers
        self.asked: list[str] = []

    def command(self, name: str, value: float = 0.0) -> CommandResult:
        self.asked.append(name)
        return self.answers.pop(0)


def _fly(drone: _Drone) -> tuple[dict[str, Any], str]:
    out: dict[str, Any] = {"steps": []}
    gcs: Any = SimpleNamespace(config=SimpleNamespace(altitude=5.0))
    with pytest.raises(mission.MissionFailed) as failed:
        mission._fly(gcs, drone, 1.0, out, lambda *a: None, threading.Event(), lambda: "")
    return out, str(failed.value)


def test_offboard_start_is_asked_again_while_the_setpoints_have_not_arrived(monkeypatch: Any) -> None:
    monkeypatch.setattr(mission, "ARMABLE_TIMEOUT_S", 0.2)     # the flight stops at "armable": enough here
    no_setpoints = CommandResult(False, f"{NO_SETPOINTS_YET} from gcs: stream setpoints first")
    drone = _Drone([no_setpoints, no_setpoints, CommandResult(True, "OFFBOARD", "OFFBOARD")])
    out, why = _fly(drone)
    assert drone.asked == ["offboard_start"] * 3
    assert [c["ok"] for c in out["commands"]] == [False, False, True]
    assert [s["step"] for s in out["steps"] if s["ok"]] == ["drone connected", "offboard_start"]
    assert why.startswith("armable")


def test_offboard_start_is_asked_again_while_px4_has_no_local_position(monkeypatch: Any) -> None:
    """Ten drones started on two cores: one's PX4 had sent no LOCAL_POSITION_NED yet when the mission asked,
    and its flight failed at once. Real PX4 has none until its estimator converges, seconds after boot."""
    from px4_link.targets import PositionTarget, TargetRefused, TargetValidator

    with pytest.raises(TargetRefused) as refused:
        TargetValidator().check_against_vehicle(PositionTarget(0.0, 0.0, -5.0), None, 5.0)
    # What the companion answers (companion/setpoint_gate.py prefixes it), as the mission reads it.
    message = f"setpoints refused: {refused.value}"
    assert POSITION_UNKNOWN in message
    monkeypatch.setattr(mission, "ARMABLE_TIMEOUT_S", 0.2)
    drone = _Drone([CommandResult(False, message), CommandResult(True, "OFFBOARD", "OFFBOARD")])
    out, why = _fly(drone)
    assert drone.asked == ["offboard_start"] * 2
    assert [s["step"] for s in out["steps"] if s["ok"]] == ["drone connected", "offboard_start"]
    assert why.startswith("armable")


def test_any_other_refusal_fails_the_mission_at_once() -> None:
    drone = _Drone([CommandResult(False, "setpoints refused: outside the fence")])
    out, why = _fly(drone)
    assert drone.asked == ["offboard_start"]
    assert why == "offboard_start: setpoints refused: outside the fence"


def test_the_setpoints_never_arriving_fails_after_the_wait(monkeypatch: Any) -> None:
    monkeypatch.setattr(mission, "OFFBOARD_START_WAIT_S", 1.5)
    refusal = CommandResult(False, f"{NO_SETPOINTS_YET} from gcs")
    drone = _Drone([refusal] * 10)
    out, why = _fly(drone)
    assert 2 <= len(drone.asked) <= 3
    assert why.startswith(f"offboard_start: {NO_SETPOINTS_YET}")


class _LateServer:
    """A command client (unicast: it discovers servers) whose drone's service turns up during a wait."""

    def __init__(self, turns_up: bool) -> None:
        self.turns_up = turns_up
        self.ready = False
        self.discovers_servers = True
        self.calls = 0
        self.waited: list[float] = []

    def service_is_ready(self) -> bool:
        return self.ready

    def wait_for_service(self, timeout: float | None = None) -> bool:
        self.waited.append(timeout or 0.0)
        self.ready = self.turns_up
        return self.ready

    def call(self, request: Any, timeout: float) -> CommandResult:
        from zenoh_robot.services import ServiceUnavailable
        self.calls += 1
        if not self.ready:
            raise ServiceUnavailable("service /uav1/command: no server")
        return CommandResult(True, request.name, "OFFBOARD")


def test_a_command_waits_for_a_service_not_yet_known_and_is_sent_once() -> None:
    from gcs.app import DroneView

    view: Any = SimpleNamespace(commands=_LateServer(turns_up=True), gcs=SimpleNamespace(
        config=SimpleNamespace(client_id="gcs")))
    res = DroneView.command(view, "offboard_start", timeout=3.0)
    assert res.success and view.commands.calls == 1 and view.commands.waited == [pytest.approx(2.4)]
    # No server within the wait: one call still goes (it fails at once, nothing sent), a failed result.
    view.commands = _LateServer(turns_up=False)
    res = DroneView.command(view, "offboard_start", timeout=0.5)
    assert not res.success and res.message == "ServiceUnavailable: service /uav1/command: no server"
    assert view.commands.calls == 1
    # A multicast client (no declarations cross) never waits: its calls ride puts.
    view.commands = _LateServer(turns_up=False)
    view.commands.discovers_servers, view.commands.ready = False, True
    assert DroneView.command(view, "hold").success and view.commands.waited == []
