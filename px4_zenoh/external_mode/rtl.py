"""``ReturnHome``: a companion's own RTL, registered with PX4 as the replacement of PX4's internal RTL.

What PX4 does with a replacement (commander/ModeManagement.cpp, PX4 main 2026-03): a mode registered with
``replace_internal_mode`` = RTL (5) is flown whenever RTL is asked for (a user, a GCS, a failsafe:
``getNavStateReplacementIfValid``), and it is hidden from the selectable modes; while its arming check is
unresponsive PX4 flies its own RTL instead, without a failsafe (a dead companion: ~1.0-1.3 s after its last
reply); a "cannot run" answer blocks PX4's own RTL too (externalChecks.cpp checkAndReport applies it to the
replaced mode), so this mode says "no" only when it truly cannot fly: no fresh position.

The flight, chosen to be simple and predictable (the same straight path every time, never lower than where
it started):
1. climb (or stay, if higher) to ``return_alt_m`` above home, straight up over the entry point;
2. fly straight to above home at that altitude;
3. descend over home, the setpoint a carrot ``DESCENT_CARROT_M`` below the vehicle (~1 m/s with PX4's
   position gains, the controller's own speed limits on top), until PX4's land detector says landed;
4. report completion (mode_completed, as PX4's RTL does once landed: rtl_direct.cpp RTLState::IDLE) and keep
   pushing down until PX4 auto-disarms.
Home is where the companion saw the vehicle arm (local NED); if it never saw an arming, the local origin (PX4's
EKF origin, which is home on a vehicle that armed where it booted). Setpoints go out only while PX4 flies this
mode (``ExternalMode`` withholds them otherwise); re-entered, it starts again from step 1.

Threading: one daemon thread registers (again after a PX4 reboot) and flies at ``rate_hz``; ``check`` runs
on Zenoh's thread and only reads.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from .bridge import BridgePolicy
from .mode import ExternalMode

log = logging.getLogger(__name__)

Position = Callable[[], "tuple[float, float, float] | None"]
NAME = "RTL (companion)"
RETURN_ALT_M = 10.0          # above home; PX4's RTL_RETURN_ALT default is 60 m, a companion's field is smaller
CLIMB_TOLERANCE_M = 0.5
ARRIVE_RADIUS_M = 0.5
DESCENT_CARROT_M = 1.0
REGISTER_RETRY_S = 2.0


class ReturnHome:
    def __init__(self, session: zenoh.Session, position: Position, landed: Callable[[], bool], *,
                 name: str = NAME, domain: int = 0, return_alt_m: float = RETURN_ALT_M, rate_hz: float = 20.0,
                 bridge: BridgePolicy | None = None, msg_dir: Path | None = None) -> None:
        self._position, self._landed = position, landed
        self.return_alt_m = return_alt_m
        self.period_s = 1.0 / rate_hz
        self.mode = ExternalMode(session, name, self.check, domain=domain, replace_internal_mode="rtl",
                                 requires_position=True, bridge=bridge, msg_dir=msg_dir)
        self.home: tuple[float, float, float] | None = None
        self.phase = ""                       # "", climb, return, descend, landed
        self.phases: list[tuple[float, str]] = []   # (monotonic time, phase entered): for tests and logs
        self._entry: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._alt = 0.0                       # the return altitude of this flight (NED z, negative up)
        self._was_armed = False
        self._stop = threading.Event()
        self._registrar = threading.Thread(target=self.mode.keep_registered, args=(self._stop, REGISTER_RETRY_S),
                                           name="px4rtl-register", daemon=True)
        self._flyer = threading.Thread(target=self._fly_loop, name="px4rtl-fly", daemon=True)
        self._registrar.start()
        self._flyer.start()

    def check(self) -> tuple[bool, tuple[str, ...]]:
        return (True, ()) if self._position() is not None else (False, ("no position for RTL",))

    # ---------------------------------------------------------------- the flight
    def _fly_loop(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self._tick()
            except Exception:   # noqa: BLE001 - one bad tick must not end the mode: PX4 would keep flying it blind
                log.exception("px4 rtl: tick failed")

    def _tick(self) -> None:
        armed, pos = self.mode.armed, self._position()
        if armed and not self._was_armed and pos is not None:
            self.home = pos                  # where it armed: home for this flight
        self._was_armed = armed
        if not self.mode.active or pos is None:
            if self.phase:
                self._enter("")
            return
        hx, hy, hz = self.home if self.home is not None else (0.0, 0.0, 0.0)
        if not self.phase and self._landed():   # asked on the ground (armed): nothing to return from
            self._enter("landed")
            self.mode.complete(True)
        if not self.phase:
            self._entry = pos
            self._alt = min(pos[2], hz - self.return_alt_m)    # never lower than now
            self._enter("climb")
        x, y, z = pos
        if self.phase == "climb":
            if z <= self._alt + CLIMB_TOLERANCE_M:
                self._enter("return")
            else:
                self.mode.trajectory((self._entry[0], self._entry[1], self._alt))
                return
        if self.phase == "return":
            if math.hypot(x - hx, y - hy) <= ARRIVE_RADIUS_M:
                self._enter("descend")
            else:
                self.mode.trajectory((hx, hy, self._alt))
                return
        if self.phase == "descend" and self._landed():
            self._enter("landed")
            self.mode.complete(True)
        self.mode.trajectory((hx, hy, z + DESCENT_CARROT_M))

    def _enter(self, phase: str) -> None:
        self.phase = phase
        self.phases.append((time.monotonic(), phase or "inactive"))
        log.info("px4 rtl: %s", phase or "inactive")

    def close(self) -> None:
        """Unregister (PX4's own RTL is RTL again) and stop."""
        self._stop.set()
        self._registrar.join(5.0)
        self._flyer.join(2.0)
        self.mode.close()
