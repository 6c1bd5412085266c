"""A PX4 SITL stand-in that speaks PX4's Zenoh protocol (``px4_sitl_zenoh``), for CI without PX4.

``ZenohSimulator`` (simulator.py) reuses px4_link.sim's vehicle model and rules; ``python -m
px4_zenoh.sim --connect <endpoint>`` runs one as a process. See docs/px4-zenoh-sim.md.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from px4_link.lazy import lazy_exports

if TYPE_CHECKING:   # loaded on first use (px4_link/lazy.py: a Ctrl-C at start-up)
    from .simulator import ZenohSimulator

__all__ = ["ZenohSimulator"]

__getattr__ = lazy_exports(__name__, {
    ".simulator": ("ZenohSimulator",),
})
