"""Live parameters with an owner (issue #24, item 4), over real Zenoh sessions with the in-process
Companion and the built-in simulator over real MAVLink/UDP: safety limits and downlink rates change
only at the request of the GCS in control, the lease stays above the deadline, every change is
published with its sender, a monitoring GCS leaves the downlink alone, and PX4 parameters written
through the companion stay within PX4's ranges."""
from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import free_port, linked_configs, python_proc, stop_process, wait_for

from companion.app import Companion
from companion.config import CompanionConfig
from companion.params import SPECS, CompanionParameters
from drone_contract.messages import Command, CommandResult, FailsafeEvent, VehicleState
from drone_contract.streams import stream_profile
from gcs.downlink import NOT_IN_CONTROL, DownlinkRates
from px4_link import Px4Link
from px4_link.sim import Simulator
from zenoh_robot import MultiThreadedExecutor, Node, ServiceCallError, SessionConfig
from zenoh_robot.parameters import InvalidParameterValueError, Parameter, ParameterClient, ParameterStore

PROFILE = stream_profile("resilient")
# The limits the issue's rogue changed, and the values it set; a holder's accepted values beside them.
SAFETY = {"max_offset_m": (100.0, 20.0), "max_speed": (30.0, 5.0), "control_lease_s": (60.0, 8.0),
          "sensor_rate_hz": (1.0, 100.0), "camera_rate_hz": (1.0, 10.0), "report_interval_s": (60.0, 1.0)}


@dataclass
class Peer:
    """A GCS-side peer with its own client id: commands, parameter sets, the events addressed to it."""
    node: Node
    ns: str
    client_id: str
    events: list[FailsafeEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.params = ParameterClient(self.node, f"/{self.ns}/companion", 5.0, client_id=self.client_id)
        self.commands = self.node.create_client(f"/{self.ns}/command", Command, CommandResult)

    def command(self, name: str, value: float = 0.0, text: str = "") -> CommandResult:
        return self.commands.call(Command(name, value, text, False, self.client_id), timeout=15.0)

    def set(self, name: str, value: float) -> tuple[bool, str]:
        (r,) = self.params.set([Parameter(name, value=value)])
        return r.successful, r.reason

    def get(self, name: str) -> object:
        (p,) = self.params.get([name])
        assert p is not None
        return p.value


@dataclass
class Rig:
    sim: Simulator
    companion: Companion
    ground: Node
    op: Peer
    rogue: Peer
    events: list[FailsafeEvent]
    states: list[VehicleState]

    def kinds(self, kind: str, client_id: str) -> list[FailsafeEvent]:
        return [e for e in list(self.events) if e.kind == kind and e.client_id == client_id]


@contextmanager
def rig(ns: str) -> Iterator[Rig]:
    listen, connect = linked_configs()
    with Px4Link("udpin:127.0.0.1:0") as link, \
            Simulator(1, port=0, target_port=link.local_port) as sim, \
            Node("companion", namespace=ns, config=listen, executor=MultiThreadedExecutor(3)) as cnode, \
            Node("ground", config=connect, executor=MultiThreadedExecutor(2)) as ground:
        assert link.wait_connected(5.0)
        comp = Companion(cnode, link, CompanionConfig(drone_id=ns, camera=None))
        events: list[FailsafeEvent] = []
        states: list[VehicleState] = []
        ground.create_subscription(FailsafeEvent, f"/{ns}/events", events.append, PROFILE.qos["events"])
        ground.create_subscription(VehicleState, f"/{ns}/state", states.append, PROFILE.qos["state"])
        for n in (cnode, ground):
            threading.Thread(target=n.spin, daemon=True).start()
        op, rogue = Peer(ground, ns, "op"), Peer(ground, ns, "rogue")
        assert op.params.wait_for_node(10.0), "no parameter service"
        assert wait_for(lambda: bool(states) and states[-1].connected, 15), "no state from the companion"
        yield Rig(sim, comp, ground, op, rogue, events, states)


def _owner_only_names() -> list[str]:
    return [s.name for s in SPECS if s.live and s.owner_only]


def test_every_safety_limit_and_downlink_rate_is_owner_only() -> None:
    names = set(_owner_only_names())
    assert set(SAFETY) <= names, set(SAFETY) - names
    assert not {s.name for s in SPECS if s.owner_only and not s.live} & names


def test_a_non_holder_is_refused_and_the_holder_is_heard_with_its_name(ns: str) -> None:
    with rig(ns) as r:
        params = r.companion.params
        # Nobody in control: nobody changes a limit (the operator takes control first).
        ok, why = r.rogue.set("max_offset_m", 100.0)
        assert not ok and "no GCS in control" in why, why
        assert r.op.command("take_control").success

        before = {n: r.op.get(n) for n in _owner_only_names()}
        refused = params.refused_owner
        for name in _owner_only_names():   # the issue's rogue, with the GCS in control
            value = SAFETY[name][0] if name in SAFETY else before[name]
            ok, why = r.rogue.set(name, value)   # type: ignore[arg-type]
            assert not ok and "only the GCS in control (op) may change it" in why and name in why, (name, why)
        assert params.refused_owner - refused == len(before)
        assert {n: r.op.get(n) for n in before} == before, "a refused write changed a value"
        assert wait_for(lambda: any("max_speed: only the GCS in control (op)" in e.detail
                                    for e in r.kinds("param_refused", "rogue")), 10), [e.kind for e in r.events]
        assert not r.kinds("param_changed", "rogue")

        # A whole request is refused when one name in it is guarded, even beside a free one.
        (a, b) = r.rogue.params.set([Parameter("sensor_rate_tolerance", value=0.5),
                                     Parameter("max_speed", value=30.0)])
        assert not a.successful and not b.successful and "max_speed" in a.reason

        for name, (_, value) in SAFETY.items():   # the holder: accepted, applied, published with its name
            ok, why = r.op.set(name, value)
            assert ok, (name, why)
            assert r.op.get(name) == value
            detail = f"{name} {before[name]!r} -> {value!r}"
            assert wait_for(lambda d=detail: any(e.detail == d for e in r.kinds("param_changed", "op")), 10), \
                (detail, [e.detail for e in r.events if e.kind == "param_changed"])
        assert r.companion.control.lease_s == SAFETY["control_lease_s"][1]   # applied, not only stored
        assert wait_for(lambda: r.states[-1].sensor_rate_requested_hz == SAFETY["sensor_rate_hz"][1], 10)
        # Not in control any more: refused again.
        assert r.op.command("release_control").success
        ok, why = r.op.set("max_speed", 6.0)
        assert not ok and "no GCS in control" in why
        assert r.companion.summary()["parameters"]["refused"] >= params.refused_owner


def test_the_lease_stays_above_the_deadline(ns: str) -> None:
    with rig(ns) as r:
        assert r.op.command("take_control").success
        deadline = r.companion.config.setpoint_deadline
        ok, why = r.op.set("control_lease_s", deadline * 0.8)
        assert not ok and f"control_lease_s {deadline * 0.8:g} s must stay above setpoint_deadline {deadline:g} s" \
            in why, why
        assert r.op.get("control_lease_s") == 5.0 and r.companion.control.lease_s == 5.0
    # ... and at start: a -p pair that breaks it stops the companion before anything opens.
    with pytest.raises(InvalidParameterValueError, match="control_lease_s 1 s must stay above setpoint_deadline 2 s"):
        CompanionParameters(CompanionConfig(setpoint_deadline=2.0, control_lease_s=1.0)).declare(ParameterStore())


def test_a_monitoring_gcs_leaves_the_downlink_alone_until_it_is_in_control(ns: str) -> None:
    with rig(ns) as r:
        assert r.op.command("take_control").success
        reports: list[tuple[str, str]] = []
        asked_before = r.companion.params.refused_owner
        dl = DownlinkRates(r.ground, {"sensor_rate_hz": 50.0}, lambda d, w: reports.append((d, w)), "monitor")
        last = [0.0]

        def on_state(msg: VehicleState) -> None:   # as gcs/app.py calls it, from the monitor's own subscription
            now = time.monotonic()
            dl.on_state(ns, last[0], now, float(msg.sensor_rate_requested_hz), msg.controller)
            last[0] = now

        r.ground.create_subscription(VehicleState, f"/{ns}/state", on_state, PROFILE.qos["state"])
        try:
            assert wait_for(lambda: ns in dl.status and dl.status[ns].status == "not_in_control", 10)
            time.sleep(1.5)   # several states later: still said once, never asked
            st = dl.status[ns]
            assert st.asked == 0 and st.answers == [NOT_IN_CONTROL], st.as_dict()
            assert r.companion.params.refused_owner == asked_before   # no request went out at all
            assert r.states[-1].sensor_rate_requested_hz == 200.0
            # In control: asked at once, and applied.
            assert r.op.command("release_control").success
            monitor = Peer(r.ground, ns, "monitor")
            assert monitor.command("take_control").success
            assert wait_for(lambda: dl.status[ns].status == "applied", 10), dl.status[ns].as_dict()
            assert wait_for(lambda: r.states[-1].sensor_rate_requested_hz == 50.0, 10)
            assert r.kinds("param_changed", "monitor")
        finally:
            dl.close()


def test_set_param_to_px4_is_checked_against_px4s_ranges(ns: str) -> None:
    with rig(ns) as r:
        res = r.op.command("set_param", 0.0, "MPC_LAND_SPEED")
        assert not res.success and "MPC_LAND_SPEED: 0 outside 0.6..4 m/s" in res.message, res.message
        res = r.op.command("set_param", 25.0, "MPC_XY_VEL_MAX")
        assert not res.success and "outside 0..20 m/s" in res.message, res.message
        assert r.sim.params["MPC_LAND_SPEED"] == pytest.approx(0.7)
        res = r.op.command("set_param", 1.0, "MPC_LAND_SPEED")
        assert res.success, res.message
        assert wait_for(lambda: abs(float(r.sim.params["MPC_LAND_SPEED"]) - 1.0) < 1e-6, 5)


def test_secure_a_second_gcs_of_the_drone_not_in_control_is_refused(tmp_path: Path) -> None:
    """--secure: the ACL lets every GCS of uav1 reach its parameter service (both certificates are
    authorised for uav1); the companion's guard still refuses the one not in control. A GCS
    certificate for another drone never reaches the service at all."""
    import cryptography  # noqa: F401  (a dev dependency: missing is a failure)

    from zenoh_robot.tools import keys

    d = tmp_path / "keys"
    keys.init_ca(d)
    for name, role, drones in (("router", "router", None), ("uav1", "drone", None), ("gcs", "gcs", ["uav1"]),
                               ("gcs2", "gcs", ["uav1"]), ("other", "gcs", ["uav9"])):
        keys.issue(d, name, role, drones)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = python_proc("-m", "zenoh_robot.tools.cli.main", "router", "--secure", str(d), "--listen", endpoint,
                         "--no-scouting", "--status", "0", "--duration", "120")

    def client(name: str) -> SessionConfig:
        return SessionConfig(secure=str(d), name=name, mode="client", listen=[], connect=[endpoint],
                             multicast_scouting=False)

    try:
        # Its first line comes once it listens (a fixed 1 s was too short for a loaded CI machine).
        # (EOF ends the wait if the router dies.)
        lines = [router.stdout.readline()]
        while lines[-1] and "listening on" not in lines[-1]:
            lines.append(router.stdout.readline())
        assert "listening on" in lines[-1], lines
        with Px4Link("udpin:127.0.0.1:0") as link, \
                Simulator(1, port=0, target_port=link.local_port) as sim, \
                Node("companion", namespace="uav1", config=client("uav1")) as cnode, \
                Node("gcs", config=client("gcs")) as g1, Node("gcs_cmd", config=client("gcs2")) as g2, \
                Node("probe", namespace="other", config=client("other")) as g3:
            assert sim is not None and link.wait_connected(5.0)
            comp = Companion(cnode, link, CompanionConfig(drone_id="uav1", camera=None))
            for n in (cnode, g1, g2, g3):
                threading.Thread(target=n.spin, daemon=True).start()
            op, second, stranger = Peer(g1, "uav1", "op"), Peer(g2, "uav1", "second"), Peer(g3, "uav1", "third")
            assert op.params.wait_for_node(20.0), "the operator's GCS cannot reach the parameter service"
            assert op.command("take_control").success
            assert second.params.wait_for_node(10.0)
            ok, why = second.set("max_offset_m", 100.0)
            assert not ok and "only the GCS in control (op) may change it" in why, why
            assert comp.config.max_offset_m == 10.0 and comp.params.refused_owner == 1
            stranger.params.timeout = 2.0
            with pytest.raises(ServiceCallError):   # denied by the ACL: no reply ever comes
                stranger.set("max_offset_m", 100.0)
            assert comp.params.refused_owner == 1
            ok, why = op.set("max_offset_m", 20.0)
            assert ok, why
            assert comp.config.max_offset_m == 20.0
    finally:
        stop_process(router, 15.0)
