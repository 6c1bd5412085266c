"""Control that cannot lapse in the air (issue #24 item 1), in-process with real parts: the built-in
simulator over real MAVLink/UDP, px4_link, the Companion and GCS objects on real Zenoh sessions.

Each test fails on the tree before #24: a release left the OFFBOARD session open with no holder and
the setpoint gate then admitted anyone; the lease released a silent holder in the air; every GCS
streamed to every drone of its list."""
from __future__ import annotations

import math
import threading
import time

from conftest import wait_for
from px4_helpers import wait_state_armable
from rigs import PROFILE, Rig, rig, take_off

from companion.offboard_session import OffboardState
from gcs.app import Gcs, GcsConfig
from px4_link.sim import Simulator
from px4_link.sim.commander import ReceivedSetpoint
from zenoh_robot import Node

ALT = 2.5
AWAY = 3.0   # the observer's target: this far east of the vehicle (well within the companion's limits)


class ReachedPx4:
    """Every setpoint the simulated PX4 receives, as it understood it (thread safe)."""

    def __init__(self, sim: Simulator) -> None:
        self.positions: list[tuple[float, float, float]] = []
        self._lock = threading.Lock()
        inner = sim.commander.on_setpoint

        def record(sp: ReceivedSetpoint) -> None:
            if sp.position is not None:
                with self._lock:
                    self.positions.append(sp.position)
            inner(sp)
        sim.commander.on_setpoint = record  # type: ignore[method-assign]

    def near(self, target: tuple[float, float, float], within: float = 0.5) -> int:
        with self._lock:
            return sum(1 for p in self.positions if math.dist(p, target) < within)

    def __len__(self) -> int:
        with self._lock:
            return len(self.positions)


def _observer_streams(r: Rig) -> tuple[float, float, float]:
    """The second client streams a target AWAY m from where the vehicle is: valid, only not its to give."""
    x, y, z = r.sim.position
    target = (x + AWAY, y, z)
    r.other.target = target
    return target


def _holds_near(r: Rig, where: tuple[float, float, float], seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        assert math.dist(r.sim.position[:2], where[:2]) < 1.0, f"moved to {r.sim.position} from {where}"
        time.sleep(0.1)


def test_release_mid_flight_holds_and_the_observer_never_steers(ns: str) -> None:
    with rig(ns) as r:
        px4 = ReachedPx4(r.sim)
        take_off(r, ALT)
        hover = r.sim.position
        intruder = _observer_streams(r)
        assert wait_for(lambda: "setpoint_rejected" in r.other.kinds("intruder"), 5)
        res = r.op.command("release_control")   # what a GCS sends on Ctrl-C, then it exits
        r.op.target = None
        assert res.success, res.message
        sent_to_px4 = len(px4)
        time.sleep(2.5)   # the observer keeps streaming: it may not move the drone
        assert px4.near(intruder) == 0, "the observer's setpoints reached PX4"
        assert len(px4) == sent_to_px4, "setpoints reached PX4 after the release"
        _holds_near(r, hover, 0.5)
        assert "holds" in res.message, res.message
        assert r.sim.mode == "AUTO.LOITER" and r.companion.control.holder == ""
        assert r.companion.lifecycle.state is OffboardState.IDLE and not r.link.offboard.streaming
        assert wait_for(lambda: "control_changed" in r.op.kinds("op"), 5)
        ev = next(e for e in r.op.events if e.kind == "control_changed" and e.client_id == "op")
        assert "HOLD" in ev.action, ev
        refused = r.companion.control.counters.refused_setpoints
        assert refused > 0 and r.companion.control.counters.by_client.get("intruder", 0) > 0
        # Outside the session its setpoints are kept as candidates only, and it is told so.
        assert wait_for(lambda: "setpoint_ignored" in r.other.kinds("intruder"), 5)
        assert r.sim.mode == "AUTO.LOITER" and r.sim.armed and not r.sim.landed


def test_gcs_exits_mid_flight_drone_holds_and_control_is_kept(ns: str) -> None:
    with rig(ns, control_lease_s=1.5) as r:
        px4 = ReachedPx4(r.sim)
        with Node("gcs_a", config=r.connect) as a_node:
            threading.Thread(target=a_node.spin, daemon=True).start()
            a = Gcs(a_node, GcsConfig(drones=[ns], pattern="hover", altitude=ALT, profile=PROFILE,
                                      client_id="op-a"))
            drone = a.drones[ns]
            assert wait_for(lambda: drone.setpoints_sent > 5, 10)
            res = drone.command("offboard_start")
            assert res.success, res.message
            wait_state_armable(drone)
            assert drone.command("arm").success
            assert wait_for(lambda: r.sim.altitude > 0.8 * ALT, 20), f"altitude {r.sim.altitude:.1f}"
            intruder = _observer_streams(r)
            assert wait_for(lambda: "setpoint_rejected" in r.other.kinds("intruder"), 5)
        # The GCS's process is gone without a word (a crash, a kill): its token and its setpoints stop.
        gone_at = time.monotonic()
        assert wait_for(lambda: r.sim.mode == "AUTO.LOITER", 4), r.sim.mode
        hover = r.sim.position
        assert wait_for(lambda: any(e.kind == "control_changed" and "not on the ground" in e.detail
                                    for e in r.op.events), 8), r.op.kinds()
        # After the lease (1.5 s), counted from the last setpoint heard, which left before the node closed.
        assert time.monotonic() - gone_at > 1.2
        _holds_near(r, hover, 1.5)
        # Still op-a's: the observer cannot claim the drone by a plain command, nor steer it.
        assert r.companion.control.holder == "op-a" and r.op.state is not None and r.op.state.controller == "op-a"
        res = r.other.command("offboard_start")
        assert not res.success and "op-a is in control" in res.message, res.message
        assert px4.near(intruder) == 0, "the observer's setpoints reached PX4"
        assert r.sim.mode == "AUTO.LOITER" and r.sim.armed
        assert [e.kind for e in r.op.events if e.kind == "control_changed" and "not on the ground" in e.detail] \
            == ["control_changed"], "the lease expiry is told once"


def test_hand_over_confirmed_by_the_named_gcs(ns: str) -> None:
    with rig(ns) as r:
        px4 = ReachedPx4(r.sim)
        take_off(r, ALT)
        x, y, z = r.sim.position
        r.other.target = (x, y, z)
        res = r.other.command("hand_over", text="op")
        assert not res.success and "does not hold control" in res.message, res.message
        res = r.op.command("hand_over", text="intruder")
        assert res.success and "intruder" in res.message, res.message
        # Until the named GCS confirms, the holder keeps control and the other is refused.
        assert wait_for(lambda: any(e.kind == "control_changed" and e.client_id == "intruder"
                                    for e in r.other.events), 5)
        assert r.companion.control.holder == "op"
        res = r.other.command("take_control")
        assert res.success and "handed over by op" in res.message, res.message
        assert r.companion.control.holder == "intruder" and r.companion.control.counters.hand_overs == 1
        assert r.companion.control.counters.takeovers == 0
        # The new holder steers; the old one is refused and told.
        target = (x + 2.0, y, z)
        r.other.target = target
        r.op.target = (x - 2.0, y, z)
        assert wait_for(lambda: math.dist(r.sim.position[:2], target[:2]) < 0.5, 10), r.sim.position
        assert px4.near(target) > 0 and px4.near((x - 2.0, y, z)) == 0
        assert wait_for(lambda: "setpoint_rejected" in r.op.kinds("op"), 5)
        assert not r.op.command("hold").success
        assert r.sim.mode == "OFFBOARD"
        assert r.other.command("land").success


def test_unconfirmed_hand_over_changes_nothing_or_holds_when_the_holder_left(ns: str) -> None:
    with rig(ns) as r:
        r.companion.control.hand_over_s = 1.5
        take_off(r, ALT)
        assert r.op.command("hand_over", text="intruder").success
        assert wait_for(lambda: any(e.kind == "control_changed" and "not confirmed" in e.detail
                                    for e in r.op.events), 6), r.op.kinds()
        assert r.companion.control.holder == "op" and r.companion.control.offer is None
        assert r.sim.mode == "OFFBOARD" and r.companion.lifecycle.state is OffboardState.ACTIVE
        res = r.other.command("take_control")   # too late
        assert not res.success and "op is in control" in res.message, res.message
        # A release naming a GCS that never confirms: the holder has left, so the drone holds.
        res = r.op.command("release_control", text="intruder")
        assert res.success and "hand-over offered" in res.message, res.message
        assert r.sim.mode == "OFFBOARD"
        assert wait_for(lambda: r.sim.mode == "AUTO.LOITER", 6), r.sim.mode
        assert wait_for(lambda: r.companion.control.holder == "", 3)
        assert r.companion.lifecycle.state is OffboardState.IDLE
        assert r.sim.armed and not r.sim.landed


def test_lease_expiry_on_the_ground_releases_control(ns: str) -> None:
    with rig(ns, control_lease_s=1.5) as r:
        assert r.op.command("take_control").success
        assert r.companion.control.holder == "op"
        # The test client has no liveliness token: it lives by the lease alone, and falls silent.
        assert wait_for(lambda: r.companion.control.holder == "", 5)
        assert wait_for(lambda: any(e.kind == "control_changed" and "liveliness lost" in e.detail
                                    for e in r.op.events), 5)


def test_gcs_not_in_control_never_streams_to_that_drone(ns: str) -> None:
    with rig(ns) as r:
        take_off(r, ALT)
        watcher = Gcs(r.ground, GcsConfig(drones=[ns], pattern="hover", altitude=ALT, profile=PROFILE,
                                          client_id="watcher"))
        drone = watcher.drones[ns]
        assert wait_for(lambda: drone.state is not None and drone.state.controller == "op", 10)
        received = r.companion.gate.received.summary().as_dict()["received"]
        time.sleep(1.5)
        assert drone.setpoints_sent == 0, "a GCS not in control streamed to the drone"
        assert not drone.may_stream
        assert "watcher" not in r.companion.control.counters.by_client
        assert r.companion.gate.received.summary().as_dict()["received"] > received   # op's still arrive
        # The GCS in control streams; when nobody holds control a GCS may stream to claim it.
        mine = Gcs(r.ground, GcsConfig(drones=[ns], pattern="hover", altitude=ALT, profile=PROFILE, client_id="op"))
        r.op.target = None
        assert wait_for(lambda: mine.drones[ns].setpoints_sent > 5, 5)
        mine.streaming = False
        res = r.op.command("release_control")
        assert res.success, res.message
        assert wait_for(lambda: drone.state is not None and drone.state.controller == "", 5)
        assert wait_for(lambda: drone.setpoints_sent > 0, 5)
        assert r.sim.mode == "AUTO.LOITER"
        watcher.streaming = False
