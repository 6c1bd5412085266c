"""Issue #24 item 2: a fence that bounds every target kind, configurable per drone, and velocity
targets that expire. Units on the fence and the predictive cut; px4_link against the built-in
simulator over real MAVLink/UDP; the Companion + Simulator in-process on real Zenoh sessions."""
from __future__ import annotations

import math
import threading
import time

import px4_helpers  # noqa: F401  (puts the checkout's px4_link first on sys.path)
import pytest
from conftest import wait_for
from px4_helpers import ReceivedSetpoints, sim_and_link
from rigs import Rig, rig, take_off

from companion.config import CompanionConfig
from companion.params import SPECS, CompanionParameters, owner_only
from drone_contract.messages import DroneSetpoint
from px4_link import Px4Link
from px4_link.targets import Geofence, PositionTarget, StoppingModel, TargetRefused, TargetValidator, VelocityTarget
from zenoh_robot.msgs import Header
from zenoh_robot.parameters import InvalidParameterValueError, Parameter, ParameterStore

STOP = StoppingModel()   # 3 m/s^2, 1 s


# ------------------------------------------------------------------------------------------ units
@pytest.mark.fast
def test_fence_bounds_radius_ceiling_and_floor_and_names_the_limit() -> None:
    f = Geofence(max_distance_m=50, max_altitude_m=30, min_altitude_m=2)
    assert f.violation(10, 10, -10) is None
    assert "radius 50 m" in (f.violation(40, 40, -10) or "")
    assert "ceiling 30 m" in (f.violation(0, 0, -31) or "")
    assert "floor 2 m" in (f.violation(0, 0, -1) or "")
    assert f.violation(math.nan, 0, -5) is not None
    # The defaults: PX4's GF_MAX_HOR_DIST / GF_MAX_VER_DIST set, and never below home.
    d = Geofence()
    assert (d.max_distance_m, d.max_altitude_m, d.min_altitude_m) == (100.0, 120.0, 0.0)
    assert "floor 0 m" in (d.violation(0, 0, 0.5) or "")


@pytest.mark.fast
def test_position_targets_below_the_floor_or_above_the_ceiling_are_refused() -> None:
    v = TargetValidator(Geofence(max_distance_m=50, max_altitude_m=30, min_altitude_m=2), max_speed=10)
    for sp, words in ((PositionTarget(0, 0, -1), "floor 2 m"), (PositionTarget(0, 0, -31), "ceiling 30 m"),
                      (PositionTarget(51, 0, -5), "radius 50 m")):
        with pytest.raises(TargetRefused) as e:
            v.check(sp, now=0.0)
        assert e.value.reason == "geofence" and words in str(e.value), str(e.value)
    v.check(PositionTarget(0, 0, -5), now=0.0)


@pytest.mark.fast
def test_velocity_targets_need_a_position_to_be_fenced() -> None:
    v = TargetValidator(Geofence(), max_speed=10)
    with pytest.raises(TargetRefused) as e:
        v.check(VelocityTarget(3, 0, 0), now=0.0)
    assert e.value.reason == "no_position"
    v.check(VelocityTarget(3, 0, 0), now=0.0, vehicle_position=(0, 0, -5))
    TargetValidator(None, max_speed=10).check(VelocityTarget(3, 0, 0), now=0.0)   # no fence: nothing to need


@pytest.mark.fast
def test_stopping_model_is_its_own_inverse() -> None:
    assert STOP.distance(9.5) == pytest.approx(9.5 * 1.0 + 9.5 ** 2 / 6)
    for d in (0.1, 1.0, 24.54, 100.0):
        assert STOP.distance(STOP.speed_within(d)) == pytest.approx(d)
    assert STOP.speed_within(0.0) == STOP.speed_within(-3.0) == 0.0


@pytest.mark.fast
def test_fence_velocity_cuts_only_what_points_out_and_only_near_the_fence() -> None:
    f = Geofence(max_distance_m=100, max_altitude_m=50, min_altitude_m=1)
    far = f.fence_velocity(VelocityTarget(9.5, 0, 0), (10.0, 0.0, -10.0), STOP)
    assert far == (VelocityTarget(9.5, 0, 0), None)                 # 90 m left: nothing to cut
    # 15 m from the fence 9.5 m/s cannot stop in time (24.5 m): cut to the speed that can.
    sent, why = f.fence_velocity(VelocityTarget(9.5, 0, 0, yaw=1.0), (85.0, 0.0, -10.0), STOP)
    assert sent.vx == pytest.approx(STOP.speed_within(15.0)) and sent.yaw == 1.0
    assert why is not None and "radius 100 m" in why and "15.0 m left" in why
    # At the fence: outward cut to nothing; along it and back in pass untouched.
    at = (100.0, 0.0, -10.0)
    assert f.fence_velocity(VelocityTarget(5, 0, 0), at, STOP)[0] == VelocityTarget(0, 0, 0)
    assert f.fence_velocity(VelocityTarget(-5, 3, 0), at, STOP) == (VelocityTarget(-5, 3, 0), None)
    sent, _ = f.fence_velocity(VelocityTarget(5, 5, 0), at, STOP)
    assert (sent.vx, sent.vy) == (pytest.approx(0.0), 5)
    # Beyond it (pushed out by wind, or a fence made smaller): only back in.
    out = (110.0, 0.0, -10.0)
    assert f.fence_velocity(VelocityTarget(2, 0, 0), out, STOP)[0].vx == pytest.approx(0.0)
    assert f.fence_velocity(VelocityTarget(-2, 0, 0), out, STOP)[1] is None
    # Diagonal: the radial component is what is cut.
    sent, _ = f.fence_velocity(VelocityTarget(5, 5, 0), (70.7, 70.7, -10.0), STOP)
    assert sent.vx + sent.vy == pytest.approx(0.0, abs=0.1)
    # Ceiling and floor: a climb at the ceiling, a descent at the floor are cut; the way back passes.
    assert f.fence_velocity(VelocityTarget(0, 0, -2), (0.0, 0.0, -50.0), STOP)[0].vz == pytest.approx(0.0)
    assert f.fence_velocity(VelocityTarget(0, 0, 1), (0.0, 0.0, -1.0), STOP)[0].vz == pytest.approx(0.0)
    assert f.fence_velocity(VelocityTarget(0, 0, -1), (0.0, 0.0, 0.0), STOP)[1] is None   # below the floor: climb
    assert f.fence_velocity(VelocityTarget(0, 0, 1), (0.0, 0.0, -1.0), STOP)[1] is not None
    assert f.fence_velocity(VelocityTarget(3, 0, 0), (math.nan, 0.0, -5.0), STOP)[0] == VelocityTarget(0, 0, 0)


@pytest.mark.fast
def test_fence_velocity_at_the_origin_uses_the_heading_as_outward() -> None:
    tiny = Geofence(max_distance_m=1.0)
    sent, why = tiny.fence_velocity(VelocityTarget(0, 9, 0), (0.0, 0.0, -5.0), STOP)
    assert why is not None and sent.vy == pytest.approx(STOP.speed_within(1.0))


# ------------------------------------------------------------------------------- companion config
@pytest.mark.fast
def test_fence_parameters_are_live_owner_only_and_bounded() -> None:
    specs = {s.name: s for s in SPECS}
    for name in ("fence_radius_m", "fence_ceiling_m", "fence_floor_m"):
        assert specs[name].live and owner_only(name), name
    cfg = CompanionParameters(CompanionConfig(camera=None)).declare(
        ParameterStore({"fence_radius_m": 40.0, "fence_floor_m": 2.0}))
    assert cfg.geofence() == Geofence(max_distance_m=40.0, max_altitude_m=120.0, min_altitude_m=2.0)
    with pytest.raises(InvalidParameterValueError, match="fence_floor_m 130 m must stay below"):
        CompanionParameters(CompanionConfig(camera=None)).declare(ParameterStore({"fence_floor_m": 130.0}))
    params = CompanionParameters(CompanionConfig(camera=None))
    params.declare(ParameterStore({}))
    changed: list[dict] = []
    params.on_change = changed.append
    assert not params.validate([Parameter("fence_radius_m", 0.0)]).successful
    assert not params.validate([Parameter("fence_ceiling_m", -1.0)]).successful   # below the floor
    assert params.validate([Parameter("fence_radius_m", 60.0)]).successful
    assert changed == [{"fence_radius_m": 60.0}] and params.config.geofence().max_distance_m == 60.0


# ------------------------------------------------------------------------- px4_link + simulator
def _airborne(sim, link: Px4Link, alt: float = 5.0) -> None:
    link.action.arm()
    link.offboard.set_setpoint(PositionTarget(0, 0, -alt, yaw=0.0))
    link.offboard.start()
    assert sim.wait_for(lambda s: s.altitude > alt - 0.3, 10), sim.position


def _stream_velocity(link: Px4Link, sp: VelocityTarget, seconds: float, track: list[float], sim) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        link.offboard.set_setpoint(sp)
        track.append(math.hypot(*sim.position[:2]))
        time.sleep(0.1)


def test_link_stops_a_velocity_stream_at_the_fence_and_reports_it_once() -> None:
    with sim_and_link(link_kwargs={"geofence": Geofence(max_distance_m=20, max_altitude_m=30)}) as (sim, link, ev):
        _airborne(sim, link)
        track: list[float] = []
        _stream_velocity(link, VelocityTarget(8.0, 0.0, 0.0), 7.0, track, sim)
        far = max(track)
        assert 17.0 < far <= 21.0, far                       # stopped at the fence, not short of it
        assert math.hypot(*sim.velocity[:2]) < 0.5, sim.velocity
        assert sim.mode == "OFFBOARD"
        assert ev.count("setpoint_clamped") == 1 and link.stats.setpoints_clamped == 1
        details = [d for _, n, d in ev.events if n == "setpoint_clamped"][0]
        assert details["reason"] == "geofence" and "radius 20 m" in details["message"]
        # Back inside is allowed: the episode ends, the vehicle comes home.
        _stream_velocity(link, VelocityTarget(-3.0, 0.0, 0.0), 1.5, track, sim)
        assert sim.wait_for(lambda s: math.hypot(*s.position[:2]) < far - 2.0, 3)


def test_link_velocity_expires_to_zero_and_a_position_is_kept() -> None:
    with sim_and_link(link_kwargs={"velocity_timeout_s": 1.0}) as (sim, link, ev):
        _airborne(sim, link)
        received = ReceivedSetpoints(sim)
        t_last = time.monotonic()
        link.offboard.set_setpoint(VelocityTarget(3.0, 0.0, 0.0))
        assert wait_for(lambda: sim.last_setpoint.velocity == (3.0, 0.0, 0.0), 2)
        assert wait_for(lambda: sim.last_setpoint.velocity == (0.0, 0.0, 0.0), 5)
        zero = next(sp for sp in received.after(t_last) if sp.velocity == (0.0, 0.0, 0.0))
        moving = [sp for sp in received.after(t_last) if sp.velocity == (3.0, 0.0, 0.0) and sp.time < zero.time]
        # Zeroed 1 s (velocity_timeout_s) after it was set: never sooner (on the simulator's clock), and no
        # more 20 Hz ticks of it than 1.3 s hold (a loaded machine runs fewer ticks, never more).
        assert zero.time - t_last > 0.95, zero.time - t_last
        assert 0 < len(moving) <= 26, len(moving)
        assert sim.wait_for(lambda s: math.hypot(*s.velocity) < 0.3, 5), sim.velocity
        assert ev.count("setpoint_expired") == 1 and link.stats.setpoints_expired == 1
        assert sim.mode == "OFFBOARD"
        # A position is a place, not a motion: re-sent long after it was set.
        x, y, z = sim.position
        link.offboard.set_setpoint(PositionTarget(x, y, z))
        time.sleep(1.5)
        n = sim.setpoints_received
        assert wait_for(lambda: sim.setpoints_received > n + 10, 1)
        assert sim.last_setpoint.position == pytest.approx((x, y, z), abs=1e-4)   # float32 on the wire
        assert link.stats.setpoints_expired == 1


# ------------------------------------------------------------------- companion + simulator (Zenoh)
def _velocity_stream(r: Rig, v: tuple[float, float, float], stop: threading.Event) -> threading.Thread:
    def run() -> None:
        while not stop.wait(0.1):
            r.op.pub.publish(DroneSetpoint(Header.now(), "op", *v, is_velocity=True))
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_a_9_5_m_s_stream_stops_at_the_drone_fence_and_the_sender_hears_why(ns: str) -> None:
    radius = 40.0
    with rig(ns, fence_radius_m=radius) as r:
        assert r.link.offboard.geofence is not None and r.link.offboard.geofence.max_distance_m == radius
        take_off(r, alt=5.0)
        assert wait_for(lambda: r.sim.mode == "OFFBOARD", 5)
        r.op.target = None
        stop = threading.Event()
        _velocity_stream(r, (9.5, 0.0, 0.0), stop)
        far = 0.0
        try:
            end = time.monotonic() + 14.0
            while time.monotonic() < end:
                far = max(far, math.hypot(*r.sim.position[:2]))
                time.sleep(0.05)
            assert r.sim.mode == "OFFBOARD" and r.companion.lifecycle.state.value == "active"
            assert math.hypot(*r.sim.velocity[:2]) < 0.5, r.sim.velocity
        finally:
            stop.set()
        print(f"fence {radius:g} m: farthest {far:.2f} m from home")
        assert radius - 3.0 < far <= radius + 1.0, far
        assert wait_for(lambda: any(e.kind == "setpoint_rejected" and "geofence" in e.detail
                                    and f"radius {radius:g} m" in e.detail for e in r.op.events
                                    if e.client_id == "op"), 3), [(e.kind, e.detail) for e in r.op.events]
        assert r.companion.gate.rejected >= 1 and r.link.stats.setpoints_clamped >= 1


def test_a_velocity_stream_that_stops_stops_the_drone_before_the_failsafe(ns: str) -> None:
    # The deadline failsafe is made slow, so only the velocity's own expiry can stop the drone.
    with rig(ns, setpoint_deadline=5.0, control_lease_s=10.0) as r:
        take_off(r, alt=5.0)
        r.op.target = None
        stop = threading.Event()
        _velocity_stream(r, (3.0, 0.0, 0.0), stop)
        assert r.sim.wait_for(lambda s: s.velocity[0] > 2.5, 5), r.sim.velocity
        received = ReceivedSetpoints(r.sim)
        stop.set()
        t_last = time.monotonic()
        assert wait_for(lambda: r.sim.last_setpoint.velocity == (0.0, 0.0, 0.0), 5.0)
        zero = next(sp for sp in received.after(t_last) if sp.velocity == (0.0, 0.0, 0.0))
        # px4_link repeats the last velocity at 20 Hz until it expires (1 s): at most 1.4 s of ticks after
        # the GCS stopped (a loaded machine runs fewer ticks, never more).
        moving = [sp for sp in received.after(t_last) if sp.velocity != (0.0, 0.0, 0.0) and sp.time < zero.time]
        assert len(moving) <= 28, len(moving)
        assert r.sim.wait_for(lambda s: math.hypot(*s.velocity) < 0.3, 5), r.sim.velocity
        print(f"zero velocity sent {zero.time - t_last:.2f} s after the last setpoint ({len(moving)} ticks of it), "
              f"drone still {time.monotonic() - t_last:.2f} s")
        assert r.sim.mode == "OFFBOARD"    # no HOLD yet: the expiry stopped it, not the failsafe
        assert wait_for(lambda: "setpoint_expired" in r.op.kinds("op"), 3), r.op.kinds()
        assert r.link.stats.setpoints_expired == 1
