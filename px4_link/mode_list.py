"""``link.modes``: the modes PX4 offers (AVAILABLE_MODES) and the one it flies (CURRENT_MODE).

PX4 (v1.15+, src/modules/mavlink/streams/AVAILABLE_MODES.hpp) answers MAV_CMD_REQUEST_MESSAGE 435 with
param2 = 0 by one AVAILABLE_MODES per valid nav state (mode_index 1..number_modes), then the ACK; the
external slots are always listed, an unregistered one as "(Mode not available)" and not user
selectable. When the list changes (a mode registered or gone) its AVAILABLE_MODES stream sends
AVAILABLE_MODES_MONITOR at 0.3 Hz with a new ``seq``: QGC asks for the list again, and so does this
plugin. CURRENT_MODE (CURRENT_MODE.hpp) comes at 0.5 Hz on every link mode (mavlink_main.cpp).

The request goes out from the send thread without waiting for its ACK: a command waits under the
command sender's one-at-a-time lock, and a list the vehicle never answers must not hold up the
companion's arming, mode changes or failsafe HOLD. The ACK is claimed here (not counted as
unsolicited) unless a caller is waiting for a REQUEST_MESSAGE ACK itself; a refusal (a PX4 before
v1.15: DENIED) stops the asking. Retried while the list is incomplete.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, NamedTuple

from .core import LinkCore
from .modes import (
    MODE_PROPERTY_ADVANCED,
    MODE_PROPERTY_NOT_USER_SELECTABLE,
    STANDARD_MODE_NAMES,
    decode_custom_mode,
    external_mode_number,
)

MAV_CMD_REQUEST_MESSAGE = 512
AVAILABLE_MODES_ID = 435
RETRY_S = 1.0          # the list not complete this long after a request: ask again
MAX_ATTEMPTS = 4       # per generation (connect, reboot, monitor change): a silent vehicle is not asked forever
ACK_WINDOW_S = 2.0     # an ACK to REQUEST_MESSAGE this long after ours is ours
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_IN_PROGRESS = 5


class AvailableMode(NamedTuple):
    """One AVAILABLE_MODES entry. ``name``: an external mode's registered name; PX4's own modes by this
    package's names (AUTO.LOITER, POSCTL: modes.py), so they read as ``state.mode`` does; an unregistered
    external slot as EXTERNAL<n> (its ``flags`` say NOT_USER_SELECTABLE)."""
    mode_index: int       # 1-based (a tuple's own ``index`` is a method)
    standard_mode: int    # MAV_STANDARD_MODE (0: none)
    custom_mode: int      # what HEARTBEAT carries in this mode
    name: str
    flags: int            # MAV_MODE_PROPERTY bits

    @property
    def selectable(self) -> bool:
        return not self.flags & MODE_PROPERTY_NOT_USER_SELECTABLE

    @property
    def advanced(self) -> bool:
        return bool(self.flags & MODE_PROPERTY_ADVANCED)

    @property
    def external(self) -> int | None:
        """n for PX4's external mode n (1..8), else None."""
        return external_mode_number(self.custom_mode)

    @property
    def standard_mode_name(self) -> str:
        return STANDARD_MODE_NAMES.get(self.standard_mode, f"UNKNOWN({self.standard_mode})")


@dataclass(frozen=True, slots=True)
class CurrentMode:
    """CURRENT_MODE: the mode PX4 shows (nav_state_display) and the one the user asked for
    (nav_state_user_intention: they differ while a failsafe flies)."""
    custom_mode: int
    intended_custom_mode: int
    standard_mode: int
    name: str              # as AvailableMode.name
    intended_name: str
    received_at: float     # monotonic


def mode_entry(m: Any) -> AvailableMode:
    """An AvailableMode from a decoded AVAILABLE_MODES."""
    raw = m.mode_name if isinstance(m.mode_name, str) else bytes(m.mode_name).decode(errors="replace")
    raw = raw.rstrip("\x00")
    custom, flags = int(m.custom_mode), int(m.properties)
    name = decode_custom_mode(custom)
    if external_mode_number(custom) is not None:
        # PX4 writes "(Mode not available)" into a free slot and flags it not selectable.
        if raw and not flags & MODE_PROPERTY_NOT_USER_SELECTABLE:
            name = raw
    elif name.startswith("UNKNOWN") and raw:
        name = raw   # a mode newer than this package: PX4's own label beats a number
    return AvailableMode(int(m.mode_index), int(m.standard_mode), custom, name, flags)


class ModeList:
    """Keeps PX4's mode list and current mode; ``Px4Link.modes``."""

    def __init__(self, core: LinkCore) -> None:
        self._core = core
        self._lock = threading.Lock()
        self._modes: tuple[AvailableMode, ...] = ()
        self._collecting: dict[int, AvailableMode] = {}
        self._collecting_total = 0
        self._current: CurrentMode | None = None
        self._wanted = 0          # generation wanted: bumped on connect, reboot and a new monitor seq
        self._have = -1           # generation the list is complete for
        self._attempts = 0        # requests sent for the wanted generation
        self._next_ask = 0.0
        self._ack_until = 0.0     # our request's ACK is expected until then
        self._refused: int | None = None   # MAV_RESULT of a refusal: the vehicle offers no list
        self._monitor_seq: int | None = None
        self.requests_sent = 0
        core.add_message_handler("AVAILABLE_MODES", self._on_mode)
        core.add_message_handler("CURRENT_MODE", self._on_current)
        core.add_message_handler("AVAILABLE_MODES_MONITOR", self._on_monitor)
        core.add_ack_filter(self._on_ack)
        core.add_event_listener(self._on_event)
        core.add_periodic(self._tick)

    # ----------------------------------------------------------------- reading
    def available(self, wait: float = 0.0) -> list[AvailableMode]:
        """The modes PX4 offers, in its order; [] before the list is complete. With ``wait`` > 0, waits
        that long at most for a complete list (or for the vehicle's refusal)."""
        if wait > 0:
            self._core.wait_until(lambda: self.complete or self._refused is not None, wait)
        return list(self._modes)

    @property
    def complete(self) -> bool:
        """The list is complete for the vehicle's current registrations (no change announced since)."""
        return self._have == self._wanted and bool(self._modes)

    @property
    def refused(self) -> int | None:
        """The MAV_RESULT with which the vehicle refused to list its modes (older PX4), else None."""
        return self._refused

    @property
    def current(self) -> CurrentMode | None:
        """The last CURRENT_MODE (PX4 sends it at 0.5 Hz)."""
        return self._current

    def refresh(self) -> None:
        """Ask for the list again (it is asked by itself on connect, reboot and when PX4 announces a change)."""
        self._want_again()

    def name_of(self, custom_mode: int) -> str:
        """A HEARTBEAT/CURRENT_MODE custom_mode by name: an external mode's registered one if known."""
        for mode in self._modes:
            if mode.custom_mode == custom_mode and mode.external is not None:
                return mode.name
        return decode_custom_mode(custom_mode)

    # ----------------------------------------------------------------- receive thread
    def _on_mode(self, m: Any) -> None:
        entry = mode_entry(m)
        total = int(m.number_modes)
        if not 1 <= entry.mode_index <= total:
            return
        done: tuple[AvailableMode, ...] | None = None
        with self._lock:
            if total != self._collecting_total:   # a different list: start over
                self._collecting, self._collecting_total = {}, total
            self._collecting[entry.mode_index] = entry
            if len(self._collecting) == total:
                done = tuple(self._collecting[i] for i in range(1, total + 1))
                self._modes = done
                self._have = self._wanted
                self._collecting, self._collecting_total = {}, 0
        if done is not None:
            self._core.set_external_mode_names({e.custom_mode: e.name for e in done
                                                if e.external is not None and e.selectable})
            self._core.emit("modes_listed", {"count": len(done)})
            self._core.notify()

    def _on_current(self, m: Any) -> None:
        custom, intended = int(m.custom_mode), int(m.intended_custom_mode)
        self._current = CurrentMode(custom, intended, int(m.standard_mode), self.name_of(custom),
                                    self.name_of(intended), time.monotonic())
        self._core.notify()

    def _on_monitor(self, m: Any) -> None:
        seq = int(m.seq)
        if seq != self._monitor_seq:
            # PX4 sends the monitor only once its list changed since boot: the first one seen may announce
            # a change made before the list was read, so it is asked for again too.
            self._monitor_seq = seq
            self._want_again()

    def _on_ack(self, command: int, result: int) -> bool:
        """An ACK addressed to us: True when it answers our own request (then nobody else sees it)."""
        if command != MAV_CMD_REQUEST_MESSAGE or time.monotonic() > self._ack_until:
            return False
        if self._core.command_in_flight() == MAV_CMD_REQUEST_MESSAGE:
            return False   # a caller waits for a REQUEST_MESSAGE ACK: the first one is theirs
        if result == MAV_RESULT_IN_PROGRESS:
            return True
        self._ack_until = 0.0
        if result != MAV_RESULT_ACCEPTED:
            self._refused = result
            self._core.notify()
        return True

    def _on_event(self, name: str, details: dict[str, Any]) -> None:
        if name in ("connected", "rebooted"):
            self._monitor_seq = None
            self._want_again()

    def _want_again(self) -> None:
        with self._lock:
            self._wanted += 1
            self._attempts = 0
            self._next_ask = 0.0
            self._refused = None

    # ----------------------------------------------------------------- send thread
    def _tick(self) -> None:
        now = time.monotonic()
        with self._lock:
            if (self._have == self._wanted or self._refused is not None or self._attempts >= MAX_ATTEMPTS
                    or now < self._next_ask or not self._core.can_send):
                return
            self._attempts += 1
            confirmation = self._attempts - 1
            self._next_ask = now + RETRY_S
            self._ack_until = now + ACK_WINDOW_S
            self._collecting, self._collecting_total = {}, 0   # a fresh answer, not a mix with an old one
            # Counted before it goes: the answer can be complete (the receive thread) before send_message returns.
            self.requests_sent += 1
        sysid, compid = self._core.vehicle_ids()
        enc = self._core.encoder()
        # param2 = 0: every mode, as QGC asks (PX4 request_message: mode_index 0 = all).
        self._core.send_message(enc.command_long_encode(sysid, compid, MAV_CMD_REQUEST_MESSAGE, confirmation,
                                                        AVAILABLE_MODES_ID, 0, 0, 0, 0, 0, 0))
