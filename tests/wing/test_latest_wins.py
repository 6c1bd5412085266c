"""Latest wins on the way to PX4 (issue #29): after a fade the companion forwards the newest
setpoint it has, never the ones recovered from the redundancy history in sequence order, and a
setpoint older than one already forwarded is dropped and counted (``stale``).

Real parts: the built-in simulator over real MAVLink/UDP, px4_link, the Companion on a real Zenoh
session linked over loopback to a ground node whose publisher's datagrams the test withholds (a fade)
or delays (a late copy)."""
from __future__ import annotations

import threading
import time
from typing import Any

from conftest import wait_for
from rigs import PROFILE, Rig, rig

from drone_contract.messages import DroneSetpoint
from drone_contract.streams import SETPOINT_DEADLINE
from px4_link.targets import Target
from zenoh_robot.msgs import Header

ALT = -2.5


class Valve:
    """Stands between a publisher and its Zenoh publisher: open, shut (a fade: datagrams lost) or
    holding (datagrams kept, to be released late)."""

    def __init__(self, zpub: Any) -> None:
        self.zpub, self.mode, self.held = zpub, "open", []   # type: list[tuple[Any, dict[str, Any]]]

    def put(self, payload: Any, **kw: Any) -> None:
        if self.mode == "open":
            self.zpub.put(payload, **kw)
        elif self.mode == "hold":
            self.held.append((payload, kw))

    def release(self) -> None:
        for payload, kw in self.held:
            self.zpub.put(payload, **kw)
        self.held.clear()

    def __getattr__(self, name: str) -> Any:    # the rest of the Zenoh publisher (undeclare, ...)
        return getattr(self.zpub, name)


def _forwarded(r: Rig) -> list[Target]:
    """Every target the companion hands to px4_link's stream (each is sent to PX4 at once)."""
    seen: list[Target] = []
    original = r.link.offboard.set_setpoint

    def spy(sp: Target, sent_at: float | None = None) -> None:
        original(sp, sent_at)
        seen.append(sp)
    r.link.offboard.set_setpoint = spy     # type: ignore[method-assign]
    return seen


def _session(r: Rig) -> None:
    r.op.target = (0.0, 0.0, ALT)
    time.sleep(0.5)
    res = r.op.command("offboard_start")
    assert res.success, res.message
    assert wait_for(lambda: r.companion.lifecycle.state.value == "active", 5.0)


def _quiet_op(r: Rig) -> None:
    """The op's own hover stream stops, and what it had in flight lands, before ours takes over:
    a hover target stamped after ours would rightly win (latest wins) and the test would read it."""
    r.op.target = None
    time.sleep(0.3)


def _publisher(r: Rig, ns: str) -> tuple[Any, Valve]:
    # No repeats: each publish is one datagram, so what the valve withholds is exactly what is lost.
    qos = PROFILE.qos["setpoint"].replace(deadline=SETPOINT_DEADLINE, repeat=0)
    pub = r.ground.create_publisher(DroneSetpoint, f"/{ns}/setpoint", qos)
    valve = Valve(pub._zpub)
    pub._zpub = valve           # every put of the publisher, its own or a repeat, goes through the valve
    if hasattr(pub, "_put"):
        pub._put = valve.put
    return pub, valve


def _send(pub: Any, i: int) -> None:
    pub.publish(DroneSetpoint(Header.now(), "op", 0.01 * i, 0.0, ALT))


def _x(sp: Target) -> int:
    return round(sp.x / 0.01)   # type: ignore[union-attr]


def test_after_a_fade_only_the_newest_recovered_setpoint_reaches_px4(ns: str) -> None:
    with rig(ns) as r:
        _session(r)
        pub, valve = _publisher(r, ns)
        seen = _forwarded(r)
        sub = r.companion.setpoint_sub
        _quiet_op(r)
        for i in range(1, 6):                      # our stream takes over from the op's at 50 Hz
            _send(pub, i)
            time.sleep(0.02)
        assert wait_for(lambda: seen and _x(seen[-1]) == 5, 3.0), seen
        before = len(seen)
        dropped, lost = sub.counters.dropped, sub.counters.lost
        arrived = len(r.companion.gate.received)
        valve.mode = "shut"                        # a 120 ms fade: samples 6..11 lost
        for i in range(6, 12):
            _send(pub, i)
            time.sleep(0.02)
        valve.mode = "open"
        _send(pub, 12)                             # carries 5..11 in its history
        assert wait_for(lambda: len(seen) > before and _x(seen[-1]) == 12, 3.0), seen[before:]
        time.sleep(0.3)
        after = [_x(sp) for sp in seen[before:]]
        assert after == [12], f"recovered samples handed to PX4 in sequence order: {after}"
        assert sub.counters.dropped - dropped == 6 and sub.counters.lost == lost   # recovered, not lost
        assert len(r.companion.gate.received) - arrived == 7      # the record of arrivals still has all 7
        assert wait_for(lambda: r.sim.last_setpoint is not None
                        and abs(r.sim.last_setpoint.position[0] - 0.12) < 1e-3, 2.0), r.sim.last_setpoint
        assert r.companion.lifecycle.state.value == "active"


def test_a_setpoint_older_than_one_forwarded_is_dropped_and_counted(ns: str) -> None:
    with rig(ns) as r:
        _session(r)
        late, late_valve = _publisher(r, ns)       # a second sender path whose datagram arrives late
        pub, _ = _publisher(r, ns)
        seen = _forwarded(r)
        stop = threading.Event()

        def stream() -> None:                      # keep the session fed (deadline 0.5 s)
            i = 100
            while not stop.wait(0.05):
                _send(pub, i)
                i += 1
        _quiet_op(r)
        _send(pub, 99)
        feeder = threading.Thread(target=stream, daemon=True)
        try:
            late_valve.mode = "hold"
            _send(late, 7)                         # stamped now, delivered later
            time.sleep(0.01)
            feeder.start()
            assert wait_for(lambda: any(_x(sp) >= 101 for sp in seen), 3.0), seen
            stale = r.companion.gate.stale
            late_valve.release()                   # the older sample arrives after newer ones
            assert wait_for(lambda: r.companion.gate.stale > stale, 5.0), \
                f"the late sample was not counted (stale {r.companion.gate.stale}, seen {[_x(sp) for sp in seen]})"
            time.sleep(0.2)
            assert 7 not in [_x(sp) for sp in seen], "an older setpoint was forwarded after a newer one"
            xs = [_x(sp) for sp in seen]
            assert xs == sorted(xs), xs
            assert r.companion.lifecycle.state.value == "active"
        finally:
            stop.set()
            if feeder.is_alive():
                feeder.join(1.0)
