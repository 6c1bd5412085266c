"""Who is the vehicle: lock onto the autopilot's address, treat everyone else as a stranger.

A MAVLink frame carries no proof of origin, so "claims system id 1" means nothing. The
link locks onto the address of the first valid autopilot HEARTBEAT and afterwards drops
(and counts) frames that claim the vehicle's ids from any other address. The lock moves
only after the locked address has fallen silent for the heartbeat timeout (a PX4 restart
on a new port), so a spoofer cannot take over while the vehicle is talking.
"""
from __future__ import annotations

import threading
from typing import Any

from .transport import Address

MAV_COMP_ID_AUTOPILOT1 = 1
MAV_AUTOPILOT_INVALID = 8
# GCS, onboard controller, gimbal, ADSB, camera, ...: not an autopilot.
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31})


def is_autopilot_heartbeat(m: Any) -> bool:
    return (m.get_type() == "HEARTBEAT" and m.type not in NON_VEHICLE_TYPES
            and m.autopilot != MAV_AUTOPILOT_INVALID
            and m.get_srcComponent() == MAV_COMP_ID_AUTOPILOT1)


class PeerLock:
    """Decides per frame: from our vehicle, from a stranger, or from an impostor."""

    def __init__(self, target_system: int | None) -> None:
        self.target_system = target_system
        self.address: Address | None = None
        self._lock = threading.Lock()

    def classify(self, m: Any, addr: Address | None, vehicle_silent: bool) -> str:
        """"vehicle", "other" (another system: ignore) or "spoofed" (our ids, wrong address)."""
        sysid = m.get_srcSystem()
        with self._lock:
            if self.target_system is None:
                if not is_autopilot_heartbeat(m):
                    return "other"
                self.target_system = sysid      # the first autopilot heard
            if sysid != self.target_system:
                return "other"
            if addr is None:                    # serial / mavutil: no addresses to check
                return "vehicle"
            if self.address is None or (vehicle_silent and addr != self.address):
                if not is_autopilot_heartbeat(m):
                    return "spoofed" if self.address is not None else "other"
                self.address = addr
                return "vehicle"
            return "vehicle" if addr == self.address else "spoofed"
