"""The companion on PX4's own Zenoh module (``--px4 zenoh:<endpoint>``), no MAVLink anywhere.

The test process runs the router PX4 would join and part D's ZenohSimulator (a Zenoh client of that
router, speaking PX4's protocol) so it can read the vehicle; the companion and the GCS are real child
processes. The flight and the failsafe HOLD on a setpoint deadline are those test_system.py checks
over MAVLink (test_gcs_killed_companion_holds_then_resumes): the same lifecycle through the other backend.
"""
from __future__ import annotations

import secrets
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import zenoh
from conftest import python_proc, stop_process, wait_for
from px4_helpers import wait_state_armable

from drone_contract.messages import Command, CommandResult, FailsafeEvent, VehicleState
from drone_contract.streams import stream_profile
from px4_zenoh.session import Px4Endpoint, free_tcp_endpoint, open_px4_session
from px4_zenoh.sim import ZenohSimulator
from zenoh_robot import Node

OP = "test-op"
FAST = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.0}


@pytest.fixture(autouse=True)
def own_domain(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ZR_DOMAIN", str(100 + secrets.randbelow(120)))


@contextmanager
def zenoh_drone(drone_id: str) -> Iterator[tuple[ZenohSimulator, subprocess.Popen[str], zenoh.Session]]:
    ep = free_tcp_endpoint()
    router = open_px4_session(Px4Endpoint("router", ep))
    try:
        with ZenohSimulator(connect=ep, sysid=1, params=FAST) as sim:
            proc = python_proc("-m", "companion", "--id", drone_id, "--px4", f"zenoh:{ep}", "--camera", "none")
            try:
                yield sim, proc, router
            finally:
                out = stop_process(proc)
                assert "Traceback" not in out, out
    finally:
        router.close()


class Observer:
    def __init__(self, node: Node, drone_id: str) -> None:
        profile = stream_profile("resilient")
        self.state: VehicleState | None = None
        self.events: list[FailsafeEvent] = []
        node.create_subscription(VehicleState, f"/{drone_id}/state", self._on_state, profile.qos["state"])
        node.create_subscription(FailsafeEvent, f"/{drone_id}/events", self.events.append, profile.qos["events"])
        self.client = node.create_client(f"/{drone_id}/command", Command, CommandResult)

    def _on_state(self, msg: VehicleState) -> None:
        self.state = msg

    def command(self, name: str, value: float = 0.0, text: str = "") -> CommandResult:
        return self.client.call(Command(name, value, text, False, OP), timeout=10.0)


def test_companion_flies_over_zenoh_and_holds_when_the_gcs_dies(ns: str) -> None:
    """arm, OFFBOARD, setpoints, the deadline HOLD (not PX4's own RTL), then land; parameters refused."""
    with zenoh_drone(ns) as (sim, companion, router), Node("observer") as node:
        obs = Observer(node, ns)
        threading.Thread(target=node.spin, daemon=True).start()
        # PX4's topics stay on the PX4 side: the GCS-facing session sees none of them.
        leaked: list[str] = []
        spy = node.session.declare_subscriber("**", lambda s: leaked.append(str(s.key_expr))
                                              if "fmu/" in str(s.key_expr) else None)
        gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", ns, "--pattern", "hover",
                          "--altitude", "2.5")
        try:
            assert wait_for(lambda: obs.state is not None and obs.state.connected, 20), "no state from the drone"
            assert wait_for(lambda: obs.command("offboard_start").success, 15, interval=0.5)
            wait_state_armable(obs)
            assert obs.command("arm").success
            assert wait_for(lambda: sim.mode == "OFFBOARD" and sim.altitude > 1.0, 20), (sim.mode, sim.altitude)
            assert sim.setpoints_received > 20
            refused = obs.command("set_param", 5.0, "MPC_XY_VEL_MAX")
            assert not refused.success and "not available over PX4's zenoh module" in refused.message
            gcs.send_signal(signal.SIGKILL)
            gcs.wait()
            killed = time.monotonic()
            assert wait_for(lambda: sim.mode == "AUTO.LOITER", 6), f"mode {sim.mode}"
            assert time.monotonic() - killed < 1.0 + 2.5
            assert not sim.failsafe_log, f"PX4's own failsafe fired: {sim.failsafe_log}"
            assert wait_for(lambda: any(e.kind == "setpoint_deadline_missed" for e in obs.events), 5)
            assert sim.armed and not sim.landed
            assert obs.command("land").success
            assert wait_for(lambda: sim.landed and not sim.armed, 30), (sim.mode, sim.altitude)
        finally:
            stop_process(gcs)
            spy.undeclare()
        assert leaked == [], leaked[:3]
        out = stop_process(companion)
    summary_line = next((ln for ln in out.splitlines() if "zenoh client of" in ln), "")
    assert summary_line, out[-2000:]
