"""The companion's answer to PX4's arming check when it flies as a PX4 external mode (``--px4-mode NAME``).

One job: say whether the companion can fly its mode now, and why not, from its own state. PX4 asks every
~310 ms (px4_zenoh.external_mode); a "no" refuses arming into the mode and, armed in it, makes PX4 leave it
for RTL. The companion's own deadline failsafe still acts first on a stale stream (HOLD before PX4's
fallback), as in OFFBOARD; this verdict keeps PX4 from arming into, or re-entering, a mode the companion
could not fly:
- no GCS holds control -> "no GCS holds control";
- the holder's token is gone and its lease ran out -> "GCS link lost";
- a session whose setpoints stopped for the deadline, or the failsafe HOLD after it -> "setpoints stale";
- no session at all (before offboard_start, after landing) -> "no offboard session".

Threading: ``check`` runs on a Zenoh callback thread; it only reads the parts' attributes (no lock, no wait).
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

from .offboard_session import OffboardState

if TYPE_CHECKING:
    from .app import Companion


class ModeReadiness:
    def __init__(self) -> None:
        self._companion: Companion | None = None

    def bind(self, companion: Companion) -> None:
        self._companion = companion

    def check(self) -> tuple[bool, tuple[str, ...]]:
        c = self._companion
        if c is None:
            return False, ("companion starting",)
        reasons: list[str] = []
        holder = c.control.holder
        if not holder:
            reasons.append("no GCS holds control")
        elif c.control.gone(holder):
            reasons.append("GCS link lost")
        state = c.lifecycle.state
        stale = state is OffboardState.ACTIVE and \
            time.monotonic() - c.failsafe.last_setpoint_at > c.config.setpoint_deadline
        if state is OffboardState.FAILSAFE_HOLD or stale:
            reasons.append("setpoints stale")
        elif state is OffboardState.IDLE:
            reasons.append("no offboard session")   # nobody arms into the mode outside one (as OFFBOARD: parked)
        return not reasons, tuple(reasons)
