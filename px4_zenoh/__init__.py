"""PX4 over Zenoh: a companion backend that drives PX4's own ``zenoh`` module (no MAVLink).

PX4 built with its ``zenoh`` module (``px4_sitl_zenoh``) is a zenoh-pico client that publishes
uORB topics as ``/fmu/out/*`` and subscribes ``/fmu/in/*`` in rmw_zenoh's wire format. This
package speaks it: ``uorb`` (px4_msgs types, CDR with PX4's trailing bytes), ``topics`` (the
topics used, their keys learnt from PX4's liveliness tokens). See docs/px4-zenoh.md.

Layering: drone wing. Imports the library (``zenoh_robot``) and ``px4_link``'s vehicle-side
types so the companion drives either backend through one interface; px4_link never imports it.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from px4_link.lazy import lazy_exports

if TYPE_CHECKING:   # loaded on first use (px4_link/lazy.py: a Ctrl-C at start-up)
    from .link import Px4ZenohLink
    from .session import PX4_DEFAULT_ENDPOINT, Px4Endpoint, parse_px4_spec

__all__ = ["Px4ZenohLink", "Px4Endpoint", "PX4_DEFAULT_ENDPOINT", "parse_px4_spec"]

__getattr__ = lazy_exports(__name__, {
    ".link": ("Px4ZenohLink",),
    ".session": ("PX4_DEFAULT_ENDPOINT", "Px4Endpoint", "parse_px4_spec"),
})
