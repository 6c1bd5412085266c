"""The companion's offboard lifecycle: when setpoints may reach PX4, and when they must not.

A small explicit state machine. PX4 flies whatever the companion streams while it is in
OFFBOARD, and real PX4 returns to OFFBOARD by itself after landing and auto-disarm; so a
stream left running after a mission makes the next ``arm`` climb to a stale target.
The rule here: setpoints stream to PX4 only inside an operator-requested session.

    IDLE --offboard_start--> STARTING --PX4 in OFFBOARD--> ACTIVE
    STARTING --refused/failed--> IDLE
    ACTIVE --setpoint deadline missed--> (HOLD commanded, then stream stops) FAILSAFE_HOLD
    FAILSAFE_HOLD --offboard_start (from the vehicle's current position)--> STARTING
    any --land / hold / rtl / disarm / offboard_stop / PX4 left OFFBOARD--> IDLE
        (the new mode is set while still streaming, then the stream stops)

Outside STARTING/ACTIVE a setpoint is never forwarded: the companion keeps the latest
valid one as the candidate an ``offboard_start`` begins from, and reports the refusal.
Every transition is logged and handed to ``on_transition`` (the companion publishes it
as a ``lifecycle`` event). Methods that talk to PX4 block on ACKs: call them from the
companion's command thread, never from a Zenoh or px4_link callback.
"""
from __future__ import annotations

import enum
import logging
import threading
from collections.abc import Callable

from px4_link.targets import Target, TargetRefused
from px4_link.vehicle import VehicleLink

log = logging.getLogger("companion.offboard")   # the name it logged under before the rename, kept

SAFE_MODE = "AUTO.LOITER"   # PX4 Hold: where the companion parks the vehicle when it stops streaming


class OffboardState(enum.StrEnum):
    IDLE = "idle"
    STARTING = "starting"
    ACTIVE = "active"
    FAILSAFE_HOLD = "failsafe_hold"


Transition = Callable[[OffboardState, OffboardState, str], None]


class OffboardLifecycle:
    def __init__(self, link: VehicleLink, on_transition: Transition) -> None:
        self.link = link
        self._on_transition = on_transition
        self._state = OffboardState.IDLE
        self._lock = threading.RLock()
        self.transitions = 0

    @property
    def state(self) -> OffboardState:
        return self._state

    @property
    def in_session(self) -> bool:
        return self._state in (OffboardState.STARTING, OffboardState.ACTIVE)

    def _go(self, new: OffboardState, why: str) -> None:
        with self._lock:
            old, self._state = self._state, new
            self.transitions += 1
        if old != new:
            log.info("offboard lifecycle: %s -> %s (%s)", old.value, new.value, why)
            self._on_transition(old, new, why)

    # -- setpoints (any thread) ----------------------------------------------------
    def forward(self, sp: Target, sent_at: float | None = None) -> None:
        """Hand ``sp`` to PX4's stream, or raise TargetRefused("no_session") when no session is open.
        ``sent_at``: the sender's time of ``sp`` (s, its clock), for px4_link's step check."""
        with self._lock:
            if not self.in_session:
                hint = ("failsafe hold: send offboard_start to resume from the vehicle's position"
                        if self._state is OffboardState.FAILSAFE_HOLD else
                        "no offboard session: send offboard_start first")
                raise TargetRefused("no_session", f"setpoint not forwarded to PX4 ({hint})")
            self.link.offboard.set_setpoint(sp, sent_at)   # px4_link's TargetRefused propagates: nothing sent

    # -- requests (command thread) -------------------------------------------------
    def start(self, candidate: Target) -> None:
        """Open a session from ``candidate`` (already checked against the vehicle)."""
        with self._lock:
            if self._state is OffboardState.ACTIVE and self.px4_in_session_mode():
                return
            self._go(OffboardState.STARTING, "offboard_start requested")
            try:
                self.link.offboard.set_setpoint(candidate)   # starts the stream PX4 needs before OFFBOARD
            except Exception:
                self._abort("first setpoint refused by px4_link")
                raise
        try:
            self.link.offboard.start()
        except Exception as exc:
            self._abort(f"PX4 refused OFFBOARD: {exc}")
            raise
        self._go(OffboardState.ACTIVE, f"PX4 in {self.link.offboard.session_mode}")

    def px4_in_session_mode(self) -> bool:
        """PX4 flies the mode sessions fly in (OFFBOARD, or the companion's external mode: --px4-mode)."""
        return self.link.mode == self.link.offboard.session_mode

    def _abort(self, why: str) -> None:
        self.link.offboard.stop_stream()
        self._go(OffboardState.IDLE, why)

    def leave(self, mode: str, why: str) -> None:
        """Switch PX4 to ``mode`` while still streaming, then stop the stream: PX4 never
        sees the stream end in OFFBOARD, and nothing streams afterwards."""
        self.link.offboard.will_leave()         # before the session ends: an external mode's check stays yes
        with self._lock:
            was = self._state
            self._go(OffboardState.IDLE, why)   # first: no setpoint arriving now restarts anything
        try:
            if self.link.offboard.streaming or was is not OffboardState.IDLE:
                self.link.offboard.stop(mode=mode)
            else:
                self.link.action.set_mode(mode)
        finally:
            self.link.offboard.stop_stream()

    def deadline_missed(self, why: str) -> bool:
        """HOLD first, then stop streaming. False when there was no session to protect."""
        with self._lock:
            if self._state is not OffboardState.ACTIVE:
                return False
            self.link.offboard.will_leave()
            self._go(OffboardState.FAILSAFE_HOLD, why)
        try:
            self.link.offboard.stop(mode=SAFE_MODE)
        finally:
            self.link.offboard.stop_stream()
        return True

    def px4_left_offboard(self, new_mode: str) -> None:
        """PX4 switched away by itself (its failsafe, RC, another GCS): stop streaming."""
        with self._lock:
            if self.in_session:
                self._go(OffboardState.IDLE, f"PX4 left OFFBOARD for {new_mode}")
            self.link.offboard.stop_stream()

    def disarmed(self) -> None:
        """Landed and disarmed (or disarmed by anyone): park PX4 in Hold, then stop streaming."""
        with self._lock:
            self._go(OffboardState.IDLE, "vehicle disarmed")
        self.park("disarmed")

    def park(self, why: str) -> bool:
        """PX4 in OFFBOARD outside a session (real PX4 returns there after landing): Hold.
        True when a mode change was sent."""
        if self.in_session:
            return False
        sent = False
        try:
            if self.link.connected and self.link.offboard.stray():
                log.warning("PX4 in %s outside a session (%s): commanding %s", self.link.mode, why, SAFE_MODE)
                self.link.offboard.stop(mode=SAFE_MODE)
                sent = True
        finally:
            self.link.offboard.stop_stream()
        return sent

    def audit(self) -> str | None:
        """The invariant, checked often: outside a session nothing streams. Returns what
        was wrong (and has been fixed), or None."""
        if not self.in_session and self.link.offboard.streaming:
            self.link.offboard.stop_stream()
            return f"stream running in state {self._state.value}: stopped"
        return None

