"""Drones found on a session: any namespace publishing the contract's state stream (``<id>/state``).

The one place that says what a drone id heard on the wire may be: the GCS app adds the
drones that appear while it runs (``watch_drones``), ``gcs cmd all`` takes the ones heard
within a few seconds (``discover_drones``). A key is chosen by whoever publishes it, so an
id that is no key chunk the apps could use (``DRONE_ID``) is never reported.

It listens on the raw Zenoh session, not through a typed subscription: a state sample's
key is all it needs, so nothing is decoded.
"""
from __future__ import annotations

import re
import time
from collections.abc import Callable
from typing import Any

from drone_contract.streams import DOWN, wired
from zenoh_robot import Node

DRONE_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
STATE_KEYS = f"*/{wired('state', DOWN).name}"
MAX_DISCOVERED = 1000   # bounded: a flood of names cannot grow what `gcs cmd all` collects


def drone_id(key: str) -> str | None:
    """The drone of a ``<id>/state`` key, or None when the id is not a valid one."""
    drone = key.split("/")[0]
    return drone if DRONE_ID.match(drone) else None


def watch_drones(node: Node, heard: Callable[[str], None]) -> Any:
    """Calls ``heard(id)`` for every state sample of a valid drone id, on Zenoh's thread (so ``heard``
    only hands over); returns the subscriber, to undeclare."""
    def on_sample(sample: Any) -> None:
        drone = drone_id(str(sample.key_expr))
        if drone is not None:
            heard(drone)
    return node.session.declare_subscriber(STATE_KEYS, on_sample)


def discover_drones(node: Node, seconds: float) -> list[str]:
    """Drone ids heard publishing ``<id>/state`` within ``seconds`` (states come at 5 Hz)."""
    found: set[str] = set()

    def heard(drone: str) -> None:
        if len(found) < MAX_DISCOVERED:
            found.add(drone)
    sub = watch_drones(node, heard)
    time.sleep(max(0.0, seconds))
    sub.undeclare()
    return sorted(found)
