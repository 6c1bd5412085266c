"""Shared helpers for the px4_link tests: simulators and links on ephemeral ports."""
from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from conftest import python_proc, skip_unless_required, wait_for  # noqa: F401  (wait_for is re-exported for the px4 tests)

from px4_link import Px4Link
from px4_link.sim import Simulator

# Faster than PX4's defaults where only test time is at stake (climb/landing rates).
FAST_PARAMS = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.0, "MIS_TAKEOFF_ALT": 2.0}
# PX4's pre-arm checks pass 4.1 s after boot (the simulator's default, test_px4_realism.py checks it against
# the SITL trace); a simulator whose test is not about that warm-up passes them after 1 s.
QUICK_WARMUP_S = 1.0


class EventLog:
    """on_event sink that tests can query."""

    def __init__(self) -> None:
        self.events: list[tuple[float, str, dict]] = []

    def __call__(self, name: str, details: dict) -> None:
        self.events.append((time.monotonic(), name, details))

    def names(self) -> list[str]:
        return [n for _, n, _ in self.events]

    def count(self, name: str) -> int:
        return self.names().count(name)


# PX4's pre-arm checks pass ~4.1 s after boot; a margin for a loaded machine.
ARMABLE_TIMEOUT_S = 15.0


def wait_armable(link: Px4Link, timeout: float = ARMABLE_TIMEOUT_S) -> None:
    """Wait, as an operator would, until PX4 says it can arm (SYS_STATUS PREARM_CHECK health bit,
    what a GCS reads); never a fixed sleep. Fails saying what PX4 last reported."""
    from px4_link.telemetry import SysStatus

    # A sample newer than now: after a PX4 restart the last one may be the old process's.
    ok = link.telemetry.wait(SysStatus, timeout, lambda s: s.armable) is not None
    assert ok, f"PX4 not armable after {timeout:g} s (mode {link.state.mode})"


def wait_state_armable(view: object, timeout: float = ARMABLE_TIMEOUT_S) -> None:
    """The same wait seen from a GCS: ``view.state`` (the drone's VehicleState over Zenoh) says
    ``armable``, as gcs/mission.py waits before its ``arm``."""
    ok = wait_for(lambda: (st := getattr(view, "state", None)) is not None and st.armable, timeout)
    st = getattr(view, "state", None)
    assert ok, f"drone not armable after {timeout:g} s (mode {st.mode if st else '?'})"


@contextmanager
def sim_and_link(sysid: int = 1, params: dict | None = None, link_kwargs: dict | None = None,
                 sim_kwargs: dict | None = None, armable: bool = True,
                 warmup_s: float = QUICK_WARMUP_S) -> Iterator[tuple[Simulator, Px4Link, EventLog]]:
    """A simulator sending to a link bound on an ephemeral localhost port, connected; with
    ``armable`` (the default) also past PX4's estimator warm-up (``warmup_s`` after boot; PX4's is
    ``px4_link.sim.commander.PX4_ESTIMATOR_WARMUP_S``), so tests that arm can at once."""
    events = EventLog()
    kw = {"on_event": events, **(link_kwargs or {})}
    with Px4Link("udpin:127.0.0.1:0", **kw) as link:
        with Simulator(sysid, port=0, target_port=link.local_port,
                       params={**FAST_PARAMS, **(params or {})}, seed=sysid,
                       **{"estimator_warmup_s": warmup_s, **(sim_kwargs or {})}) as sim:
            assert link.wait_connected(5.0), "link never saw the simulator's heartbeat"
            if armable:
                wait_armable(link)
            yield sim, link, events


class ReceivedSetpoints:
    """Every setpoint the simulator received from now on, as it understood it (time, position, velocity)."""

    def __init__(self, sim: Any) -> None:
        self.items: list[Any] = []
        inner = sim.commander.on_setpoint

        def record(sp: Any) -> None:
            self.items.append(sp)
            inner(sp)
        sim.commander.on_setpoint = record

    def after(self, t: float) -> list[Any]:
        return [sp for sp in list(self.items) if sp.time >= t]


def switched_at(sim: Any, mode: str, since: float = 0.0) -> float:
    """When the simulator switched into ``mode`` (its mode log's time: the physics step that did it, on
    time.monotonic()'s clock), the first switch at or after ``since``. A duration taken from the
    simulator's own records holds on a loaded machine, where this thread may look late."""
    times = [c.time for c in sim.mode_log if c.new == mode and c.time >= since]
    assert times, f"never switched to {mode} after {since:.3f}: {[(c.new, c.reason) for c in sim.mode_log]}"
    return times[0]


def silent_to(sim: Any, mode: str) -> float:
    """Seconds from the last setpoint the simulator received to its switch into ``mode`` after it."""
    last = sim.last_setpoint
    assert last is not None, "no setpoint ever reached the simulator"
    return switched_at(sim, mode, last.time) - last.time


def sim_process(sysid: int, target_port: int, *extra: str):
    """``python -m px4_link.sim`` as a real child process."""
    return python_proc("-m", "px4_link.sim", "--sysid", str(sysid), "--port", "0",
                       "--target-port", str(target_port), *extra)


# ---------------------------------------------------------------- a ground station
@contextmanager
def gcs_heartbeats(port: int, mav_type: int | None = None) -> Iterator[threading.Event]:
    """A QGC-like peer: HEARTBEAT at 1 Hz to the simulator until the yielded event is set."""
    from pymavlink.dialects.v20 import common as mavlink2
    if mav_type is None:
        mav_type = mavlink2.MAV_TYPE_GCS
    stop = threading.Event()
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    hb = mav.heartbeat_encode(mav_type, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(mav)

    def run() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not stop.is_set():
                s.sendto(hb, ("127.0.0.1", port))
                stop.wait(1.0)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    try:
        yield stop
    finally:
        stop.set()
        t.join(2)


# ---------------------------------------------------------------- PX4's own failsafes
def px4_failsafes(sim: Any) -> list[str]:
    """Every sign that PX4's own failsafe logic acted, whichever mode it picked (POSCTL,
    AUTO.RTL, AUTO.LAND, AUTO.LOITER, TERMINATION, ...): a failsafe record, or a switch into
    any failsafe mode that neither the user nor a finished manoeuvre asked for."""
    from px4_link.sim import FAILSAFE_MODES

    out = [f"failsafe {e.cause} -> {e.action}" for e in sim.failsafe_log]
    out += [f"{c.old} -> {c.new} ({c.reason})" for c in sim.mode_log
            if c.new in FAILSAFE_MODES and (c.reason.startswith("failsafe") or c.reason.startswith("mode fallback"))]
    if sim.commander.failsafe:    # what HEARTBEAT's system_status CRITICAL (MAVLink) / vehicle_status.failsafe report
        out.append("failsafe active (system_status CRITICAL)")
    return out


def assert_no_px4_failsafe(sim: Any) -> None:
    fired = px4_failsafes(sim)
    assert not fired, f"PX4's own failsafe fired: {fired}"


# ---------------------------------------------------------------- real PX4 SITL traces
# The traces live in the shared folder beside the clone (../shared/px4_traces), as on CI;
# ZR_PX4_TRACES points elsewhere.
TRACES = Path(os.environ.get("ZR_PX4_TRACES", Path(__file__).resolve().parents[2] / "shared" / "px4_traces"))


def trace_messages(name: str) -> list:
    """All messages of a trace tlog. Without the traces the test is skipped, saying why; where CI asks
    for everything (ZR_REQUIRE_NETNS=1) it fails instead, so the realism checks never vanish there."""
    from pymavlink import mavutil

    path = TRACES / name
    if not path.exists():
        skip_unless_required(f"the PX4 SITL traces are not at {path} (set ZR_PX4_TRACES)")
    conn = mavutil.mavlink_connection(str(path), dialect="common")
    out = []
    while (m := conn.recv_match()) is not None:
        out.append(m)
    return out
