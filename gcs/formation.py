"""Formation slots: where each drone of a swarm flies its pattern, so no two share a point.

A drone's slot is a horizontal offset in the shared local NED frame (the drones' common
origin: every built-in simulator starts at 0, 0; real vehicles need a common EKF origin).
The slot of the i-th drone depends only on i and the spacing, never on how many drones
there are, so a drone joining later never moves the others. All drones of a formation run
the pattern on one clock: each flies the same path shifted by its slot, so the distance
between any two stays their slots' distance (>= spacing) the whole flight.

``lead()`` keeps a target within reach: a drone that is far from its slot (taking off,
joining late) is led there at most ``max_lead`` metres ahead of where it is, never asked
to jump (the companion refuses a setpoint more than 10 m away).
"""
from __future__ import annotations

import math

FORMATIONS = ("auto", "none", "line", "grid")
GRID_COLUMNS = 5


def slot(index: int, kind: str, spacing: float) -> tuple[float, float]:
    """(north, east) offset of the ``index``-th drone; (0, 0) for ``none``."""
    if index < 0:
        raise ValueError(f"slot index must be >= 0, got {index}")
    if kind == "none":
        return 0.0, 0.0
    if kind == "line":     # abreast, eastwards
        return 0.0, index * spacing
    if kind == "grid":     # rows of GRID_COLUMNS, eastwards then southwards
        row, col = divmod(index, GRID_COLUMNS)
        return -row * spacing, col * spacing
    raise ValueError(f"unknown formation {kind!r}; choose one of {', '.join(FORMATIONS)}")


def resolve(kind: str, drones: int) -> str:
    """``auto``: one drone flies from where it is (``none``), several fly abreast (``line``)."""
    if kind == "auto":
        return "none" if drones == 1 else "line"
    if kind not in FORMATIONS:
        raise ValueError(f"unknown formation {kind!r}; choose one of {', '.join(FORMATIONS)}")
    return kind


def lead(x: float, y: float, tx: float, ty: float, max_lead: float) -> tuple[float, float]:
    """The target (tx, ty) moved towards (x, y) until at most ``max_lead`` away from it."""
    d = math.hypot(tx - x, ty - y)
    if d <= max_lead or not math.isfinite(d):
        return tx, ty
    k = max_lead / d
    return x + (tx - x) * k, y + (ty - y) * k
