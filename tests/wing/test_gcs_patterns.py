"""GCS setpoint patterns: continuous paths at the requested altitude."""
from __future__ import annotations

import math

import pytest

from gcs.patterns import PATTERNS, make_pattern, path_distance


@pytest.mark.parametrize("name", PATTERNS)
def test_patterns_hold_altitude_and_move_continuously(name: str) -> None:
    f = make_pattern(name, altitude=5.0, size=10.0, speed=2.0)
    prev = f(0.0)
    for i in range(1, 400):
        cur = f(i * 0.1)
        assert cur.z == -5.0
        assert math.hypot(cur.x - prev.x, cur.y - prev.y) <= 2.0 * 0.1 + 1e-9 or name == "thesis"
        if name not in ("thesis",):
            assert path_distance(cur.x, cur.y, name, 10.0) < 1e-6
        prev = cur


def test_square_visits_all_corners() -> None:
    f = make_pattern("square", size=10.0, speed=2.0)
    corners = {(round(f(t).x), round(f(t).y)) for t in (0.0, 5.0, 10.0, 15.0)}
    assert corners == {(0, 0), (10, 0), (10, 10), (0, 10)}


def test_unknown_pattern() -> None:
    with pytest.raises(ValueError, match="unknown pattern 'zigzag'"):
        make_pattern("zigzag")
