"""Setpoint patterns the GCS streams: the thesis's advertiser and simple missions.

Positions are local NED metres as PX4 uses them (z negative is up). Each pattern is a
pure function of time since start, so a restarted GCS resumes the same path.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

PATTERNS = ("thesis", "hover", "square", "circle", "line")


@dataclass(frozen=True, slots=True)
class PathPoint:
    """A point of a pattern's path (local NED metres, yaw radians) that the GCS turns into a setpoint."""

    x: float
    y: float
    z: float
    yaw: float = 0.0


def make_pattern(name: str, altitude: float = 5.0, size: float = 10.0, speed: float = 2.0,
                 ) -> Callable[[float], PathPoint]:
    """Return f(t) -> PathPoint for pattern ``name``; ``altitude`` is metres above home."""
    z = -abs(altitude)
    if name == "thesis":
        # The thesis's advertiser: x increasing at 0.1 per message (10 Hz), y and z constant.
        return lambda t: PathPoint(t * 1.0, 1.0, z)
    if name == "hover":
        return lambda t: PathPoint(0.0, 0.0, z)
    if name == "line":
        return lambda t: PathPoint(size * _triangle(t * speed / size), 0.0, z)
    if name == "square":
        perimeter = 4 * size

        def square(t: float) -> PathPoint:
            d = (t * speed) % perimeter
            side, along = int(d // size), d % size
            x, y = [(along, 0.0), (size, along), (size - along, size), (0.0, size - along)][side]
            return PathPoint(x, y, z, yaw=[0.0, math.pi / 2, math.pi, -math.pi / 2][side])
        return square
    if name == "circle":
        radius = size / 2
        omega = speed / radius

        def circle(t: float) -> PathPoint:
            a = omega * t
            return PathPoint(radius * math.sin(a), radius * (1 - math.cos(a)), z, yaw=a)
        return circle
    raise ValueError(f"unknown pattern {name!r}; choose one of {', '.join(PATTERNS)}")


def _triangle(u: float) -> float:
    """0 -> 1 -> 0 over each unit of u."""
    frac = u % 2.0
    return frac if frac <= 1.0 else 2.0 - frac


def path_distance(x: float, y: float, pattern: str, size: float = 10.0) -> float:
    """Horizontal distance from (x, y) to the pattern's path (for the demo's summary)."""
    if pattern == "square":
        cx, cy = min(max(x, 0.0), size), min(max(y, 0.0), size)
        if 0 < x < size and 0 < y < size:   # inside: distance to the nearest edge
            return min(x, y, size - x, size - y)
        return math.hypot(x - cx, y - cy)
    if pattern == "circle":
        r = size / 2
        return abs(math.hypot(x, y - r) - r)
    if pattern == "line":
        cx = min(max(x, 0.0), size)
        return math.hypot(x - cx, y)
    if pattern == "hover":
        return math.hypot(x, y)
    return 0.0
