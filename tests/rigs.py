"""Flying rigs shared by the drone tests: a drone as the GCS sees it, on the built-in simulator.

- ``rig(ns)``: everything in the test process, real parts: the simulator over real MAVLink/UDP,
  px4_link, the Companion object on a real Zenoh session linked over loopback to a ``ground`` node
  with two GCS-side ``Client`` peers (``op`` and ``intruder``). ``take_off(r)`` flies it up.
- ``drone(id)``: the companion as a real child process (``python -m companion``), the simulator in
  the test process (PX4 over MAVLink/UDP, or over PX4's own Zenoh module); ``Observer`` is a
  test-side node with its state, events and command service; ``gcs_proc`` a real GCS process.
"""
from __future__ import annotations

import contextlib
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import pytest
from conftest import free_port, linked_configs, python_proc, stop_process, wait_for
from px4_helpers import QUICK_WARMUP_S, wait_state_armable

from companion.app import Companion
from companion.config import CompanionConfig
from drone_contract.messages import Command, CommandResult, DroneSetpoint, FailsafeEvent, VehicleState
from drone_contract.streams import SETPOINT_DEADLINE, stream_profile
from px4_link import Px4Link
from px4_link.sim import Simulator
from zenoh_robot import MultiThreadedExecutor, Node, SessionConfig, qos
from zenoh_robot.msgs import Header

# Shorter climbs and landings (only test time is at stake); failsafe parameters untouched.
FAST = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.0}
# rig()'s and drone()'s vehicle, whose take-off and landing no test of theirs is about: motors up in 0.3 s
# and the climb-rate ramp over 0.5 s (PX4: 1 s and 3 s; arm -> 2.5 m in ~3 s, not ~4.7 s), disarmed 0.5 s
# after the land detector (PX4: 2 s), and PX4's pre-arm checks passing after QUICK_WARMUP_S (PX4 SITL:
# 4.1 s). The simulator's own timings are px4_link's tests (test_px4_realism.py, test_sim_failsafes.py).
QUICK_FLIGHT = {**FAST, "COM_SPOOLUP_TIME": 0.3, "MPC_TKO_RAMP_T": 0.5, "COM_DISARM_LAND": 0.5}
PROFILE = stream_profile("resilient")
OP = "test-op"   # the GCS id of drone()'s tests: their processes and nodes share it
SETPOINT_QOS = qos.RESILIENT.replace(deadline=SETPOINT_DEADLINE)   # what the companion accepts
# The HIGHRES_IMU rate rig()'s and drone()'s companions ask of PX4 unless a test asks another: the default
# (200 Hz asked, ~123 Hz given) doubles an idle companion's and its simulator's CPU (17 % of a core against
# 10 %), which three test workers on two cores pay for every flight; the sensor's tests ask it themselves.
RIG_SENSOR_HZ = 20.0


# ------------------------------------------------------------------------ in-process rig
@dataclass
class Client:
    """A test GCS-side peer with its own id: streams setpoints, sends commands, hears events."""
    node: Node
    ns: str
    client_id: str
    state: VehicleState | None = None
    events: list[FailsafeEvent] = field(default_factory=list)
    target: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        q = PROFILE.qos
        self.node.create_subscription(VehicleState, f"/{self.ns}/state", self._on_state, q["state"])
        self.node.create_subscription(FailsafeEvent, f"/{self.ns}/events", self.events.append, q["events"])
        self.pub = self.node.create_publisher(DroneSetpoint, f"/{self.ns}/setpoint",
                                              q["setpoint"].replace(deadline=SETPOINT_DEADLINE))
        self.client = self.node.create_client(f"/{self.ns}/command", Command, CommandResult)
        self._stop = threading.Event()
        threading.Thread(target=self._stream, daemon=True).start()

    def _on_state(self, msg: VehicleState) -> None:
        self.state = msg

    def _stream(self) -> None:
        while not self._stop.wait(0.1):
            t = self.target
            if t is not None:
                self.pub.publish(DroneSetpoint(Header.now(), self.client_id, *t))

    def command(self, name: str, value: float = 0.0, text: str = "", force: bool = False) -> CommandResult:
        return self.client.call(Command(name, value, text, force, self.client_id), timeout=15.0)

    def kinds(self, client_id: str | None = None) -> list[str]:
        return [e.kind for e in self.events if client_id is None or e.client_id == client_id]

    def close(self) -> None:
        self._stop.set()


@dataclass
class Rig:
    sim: Simulator
    link: Px4Link
    companion: Companion
    op: Client
    other: Client
    ground: Node
    connect: SessionConfig    # for another GCS's own session


@contextmanager
def rig(ns: str, **config: object) -> Iterator[Rig]:
    """The companion (``config``: CompanionConfig fields) on a simulator, its state already heard by ``op``."""
    listen, connect = linked_configs()
    with Px4Link("udpin:127.0.0.1:0") as link, \
            Simulator(1, port=0, target_port=link.local_port, params=QUICK_FLIGHT,
                      estimator_warmup_s=QUICK_WARMUP_S) as sim, \
            Node("companion", namespace=ns, config=listen, executor=MultiThreadedExecutor(3)) as cnode, \
            Node("ground", config=connect, executor=MultiThreadedExecutor(2)) as ground:
        assert link.wait_connected(5.0)
        config.setdefault("sensor_rate_hz", RIG_SENSOR_HZ)
        comp = Companion(cnode, link, CompanionConfig(drone_id=ns, camera=None, **config))  # type: ignore[arg-type]
        for n in (cnode, ground):
            threading.Thread(target=n.spin, daemon=True).start()
        op, other = Client(ground, ns, "op"), Client(ground, ns, "intruder")
        try:
            assert wait_for(lambda: op.state is not None and op.state.connected
                            and all(v == v for v in op.state.position), 15), "no state from the companion"
            yield Rig(sim, link, comp, op, other, ground, connect)
        finally:
            op.close()
            other.close()


def streams_to_companion(r: Rig, c: Client, timeout: float = 5.0) -> None:
    """Wait until the companion holds a setpoint from ``c`` that arrived after this call and was accepted:
    the candidate an ``offboard_start`` begins from, as a GCS's streamed setpoints give it before it asks."""
    since = time.monotonic()

    def fresh() -> bool:
        cand = r.companion.gate._candidates.get(c.client_id)
        return cand is not None and cand.at >= since and cand.sp is not None
    assert wait_for(fresh, timeout), f"no accepted setpoint from {c.client_id} reached the companion"


def take_off(r: Rig, alt: float = 2.5) -> None:
    """``op`` streams a hover ``alt`` m above home, opens OFFBOARD, arms once PX4 says it can, and climbs."""
    r.op.target = (0.0, 0.0, -alt)
    streams_to_companion(r, r.op)
    res = r.op.command("offboard_start")
    assert res.success, res.message
    wait_state_armable(r.op)
    assert r.op.command("arm").success
    assert wait_for(lambda: r.sim.altitude > alt * 0.8, 20), f"altitude {r.sim.altitude:.1f}"


# ------------------------------------------------------------------------ companion process
@contextmanager
def drone(drone_id: str, sysid: int = 1, *extra: str,
          backend: str = "mavlink") -> Iterator[tuple[Any, subprocess.Popen]]:
    """A companion process and its simulator in this process: PX4 over MAVLink (px4_link.sim, UDP) or over
    PX4's own Zenoh module (px4_zenoh.sim, a client of a router here, as PX4 joins one); the vehicle is rig()'s
    quicker one. Its output must hold no traceback when it stops."""
    from px4_zenoh.session import Px4Endpoint, free_tcp_endpoint, open_px4_session
    from px4_zenoh.sim import ZenohSimulator
    with contextlib.ExitStack() as stack:
        if backend == "mavlink":
            port = free_port()     # below the ephemeral range: no simulator's own port=0 socket draws it
            sim: Any = stack.enter_context(Simulator(sysid, port=0, target_port=port, params=QUICK_FLIGHT,
                                                     estimator_warmup_s=QUICK_WARMUP_S))
            px4 = f"udpin:127.0.0.1:{port}"
        else:
            ep = free_tcp_endpoint()
            stack.callback(open_px4_session(Px4Endpoint("router", ep)).close)
            sim = stack.enter_context(ZenohSimulator(connect=ep, sysid=sysid, params=QUICK_FLIGHT,
                                                     estimator_warmup_s=QUICK_WARMUP_S))
            px4 = f"zenoh:{ep}"
        rate = () if "--sensor-rate" in extra else ("--sensor-rate", f"{RIG_SENSOR_HZ:g}")
        proc = python_proc("-m", "companion", "--id", drone_id, "--px4", px4, "--camera-rate", "15", *rate, *extra)
        try:
            yield sim, proc
        finally:
            out = stop_process(proc, 10.0)
            assert "Traceback" not in out, out


BACKENDS = pytest.mark.parametrize("backend", ["mavlink", "zenoh"])


def gcs_proc(*args: str) -> subprocess.Popen:
    """A real GCS process (no dashboard) with drone()'s GCS id."""
    return python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, *args)


def offboard_started(obs: "Observer", gcs: subprocess.Popen, timeout: float = 20.0) -> None:
    """``obs`` asks ``offboard_start`` until the GCS process's setpoints have reached the drone. If they
    never do, the failure carries what the GCS printed: why it did not stream (it found another /gcs in
    the domain, it never heard the drone, ...), which the drone's refusal alone cannot say."""
    said: list[str] = []

    def start() -> bool:
        res = obs.command("offboard_start")
        said.append(res.message)
        return bool(res.success)
    if not wait_for(start, timeout, interval=0.5):
        raise AssertionError(f"offboard_start refused for {timeout:g} s ({said[-2:]}); the GCS printed:\n"
                             f"{stop_process(gcs)[-3000:]}")


class Observer:
    """A test-side node: the drone's state and events, and its command service."""

    def __init__(self, node: Node, drone_id: str) -> None:
        self.state: VehicleState | None = None
        self.events: list[FailsafeEvent] = []
        node.create_subscription(VehicleState, f"/{drone_id}/state", self._on_state, PROFILE.qos["state"])
        node.create_subscription(FailsafeEvent, f"/{drone_id}/events", self.events.append, PROFILE.qos["events"])
        self.client = node.create_client(f"/{drone_id}/command", Command, CommandResult)

    def _on_state(self, msg: VehicleState) -> None:
        self.state = msg

    def command(self, name: str, value: float = 0.0, text: str = "") -> CommandResult:
        return self.client.call(Command(name, value, text, False, OP), timeout=10.0)


def spin(node: Node) -> None:
    """``node.spin()`` on a daemon thread (it ends when the node closes)."""
    threading.Thread(target=node.spin, daemon=True).start()
