"""The GCS's target planning without a node: targets start where the drone is, a pattern is flown from
its anchor, a formation drone is led to its slot within reach, and the path error counts from the path."""
from __future__ import annotations

import math
from typing import Any

import pytest

from gcs.formation import slot
from gcs.planner import MAX_LEAD_M, MAX_TARGET_SPEED, PATH_JOIN_M, FormationClock, TargetPlanner


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def planner(pattern: str = "line", clock: FakeClock | None = None, **kw: Any) -> TargetPlanner:
    settings: dict[str, Any] = {"altitude": 5.0, "size": 10.0, "speed": 2.0, "rate_hz": 10.0, **kw}
    return TargetPlanner(pattern, clock=clock or FakeClock(), **settings)


def test_no_position_or_a_landing_drone_gets_no_target() -> None:
    p = planner()
    assert p.target(None, session_active=False) is None
    p.done = True
    assert p.target((0.0, 0.0, 0.0), session_active=True) is None


def test_before_the_session_the_target_follows_the_drone_and_climbs_within_reach() -> None:
    p = planner(altitude=20.0)
    t = p.target((3.0, 4.0, 0.0), session_active=False)
    assert t is not None and (t.x, t.y, t.z) == (3.0, 4.0, -MAX_LEAD_M)   # 20 m asked, MAX_LEAD_M ahead
    t = p.target((6.0, -1.0, -18.0), session_active=False)
    assert t is not None and (t.x, t.y, t.z) == (6.0, -1.0, -20.0)


def test_an_active_session_holds_where_it_began_until_the_pattern_starts() -> None:
    p = planner(fly=False)
    p.target((1.0, 2.0, -1.0), session_active=False)
    t = p.target((1.5, 2.5, -3.0), session_active=True)   # drifted: the hold stays where the session began
    assert t is not None and (t.x, t.y, t.z) == (1.0, 2.0, -5.0)


def test_the_pattern_is_flown_from_where_the_drone_was() -> None:
    clock = FakeClock()
    p = planner("line", clock)
    t = p.target((3.0, 4.0, -5.0), session_active=True)
    assert t is not None and (t.x, t.y) == (3.0, 4.0) and p.on_path
    clock.t += 2.0                                           # 2 m/s along x
    t = p.target((3.5, 4.0, -5.0), session_active=True)
    assert t is not None and (t.x, t.y, t.z) == pytest.approx((7.0, 4.0, -5.0))
    p.target((3.5, 4.0, -5.0), session_active=False)         # the session ends: the anchor goes with it
    assert not p.on_path


def test_freeze_keeps_the_target_and_start_pattern_anchors_afresh() -> None:
    clock = FakeClock()
    p = planner("line", clock)
    p.target((0.0, 0.0, -5.0), session_active=True)
    clock.t += 1.0
    p.freeze((1.0, 0.0, -5.0), session_active=True)
    clock.t += 5.0
    t = p.target((1.0, 0.0, -5.0), session_active=True)
    assert t is not None and t.x == pytest.approx(2.0) and not p.fly
    p.start_pattern()
    t = p.target((1.0, 0.0, -5.0), session_active=True)   # from the hover point, not a jump
    assert t is not None and t.x == pytest.approx(0.0) and p.fly


def test_formation_drones_fly_one_clock_in_their_own_slots() -> None:
    clock = FakeClock()
    shared = FormationClock(clock)
    spacing = 5.0
    a, b = (planner("line", clock, formation="line", slot=slot(i, "line", spacing), formation_clock=shared)
            for i in range(2))
    for _ in range(50):   # both in their slots: each is sent its own copy of the path
        clock.t += 0.1
        ta = a.target((a.slot[0] + 0.0, a.slot[1], -5.0), session_active=True)
        tb = b.target((b.slot[0] + 0.0, b.slot[1], -5.0), session_active=True)
        assert ta is not None and tb is not None
        assert math.dist((ta.x, ta.y), (tb.x, tb.y)) == pytest.approx(spacing)


def test_a_drone_far_from_its_slot_is_led_there_within_reach_and_speed() -> None:
    clock = FakeClock()
    p = planner("hover", clock, formation="line", slot=(0.0, 40.0))
    prev = p.target((0.0, 0.0, -5.0), session_active=True)
    assert prev is not None and not p.on_path
    for _ in range(20):
        clock.t += 0.1
        t = p.target((0.0, 0.0, -5.0), session_active=True)
        assert t is not None
        assert math.hypot(t.x, t.y) <= MAX_LEAD_M + 1e-9                                   # within reach
        assert math.dist((t.x, t.y), (prev.x, prev.y)) <= MAX_TARGET_SPEED / 10.0 + 1e-9   # no jump
        prev = t


def test_a_led_target_keeps_its_speed_when_the_ticks_bunch() -> None:
    """A loaded GCS's timer fires late, then at once again (the executor keeps the phase): the target moves
    by the time between the two, not a step per call, so the drone's step check never sees 10 m/s
    (the old per-call step: 0.5 m in 5 ms)."""
    clock = FakeClock()
    p = planner("hover", clock, formation="line", slot=(0.0, 40.0))
    prev, at = p.target((0.0, 0.0, -5.0), session_active=True), clock.t
    assert prev is not None
    for gap in (0.1, 0.195, 0.005, 0.1, 0.099, 0.001, 0.3, 0.0):
        clock.t += gap
        t = p.target((0.0, 0.0, -5.0), session_active=True)
        assert t is not None
        moved = math.dist((t.x, t.y), (prev.x, prev.y))
        assert moved <= MAX_TARGET_SPEED * (clock.t - at) + 1e-9, (gap, moved)
        prev, at = t, clock.t
    assert prev.y > 0.0      # and it does get on its way


def test_the_path_error_counts_once_the_drone_has_joined_its_path() -> None:
    p = planner("line", formation="line", slot=(0.0, 10.0))
    p.track((0.0, 0.0, -5.0), offboard=True)      # no session yet: nothing counted
    assert p.path_error_samples == 0
    p.target((0.0, 9.9, -5.0), session_active=True)
    p.track((0.0, 0.0, -5.0), offboard=True)      # 10 m off: still on its way, not an error
    assert p.path_error_samples == 0 and not p.on_path
    p.track((0.0, 10.0 + PATH_JOIN_M / 2, -5.0), offboard=True)
    p.track((0.0, 10.0 + 3.0, -5.0), offboard=True)   # once joined, every error counts
    assert p.on_path and p.path_error_samples == 2
    assert p.max_path_error == pytest.approx(3.0)
    assert p.mean_path_error == pytest.approx((PATH_JOIN_M / 2 + 3.0) / 2)
    p.track((0.0, 20.0, -5.0), offboard=False)        # not in OFFBOARD: not the path flown
    assert p.path_error_samples == 2


def test_the_formation_clock_starts_with_the_first_drone_to_fly() -> None:
    clock = FakeClock()
    shared = FormationClock(clock)
    clock.t += 7.0
    assert shared.elapsed() == 0.0
    clock.t += 1.5
    assert shared.elapsed() == 1.5
