"""The simulator's mode list as PX4's MAVLink module reports it: AVAILABLE_MODES, AVAILABLE_MODES_MONITOR.

From PX4's source: the list is vehicle_status.valid_nav_states_mask, the selectable ones its
can_set_nav_states_mask (commander/ModeManagement.cpp getModeStatus: mode_util::getValidNavStates(), all
selectable but TERMINATION, plus the eight external slots, each valid whether registered or not and
selectable only when registered; a registered replacement hides the internal mode it replaces).
Each entry (mavlink/streams/AVAILABLE_MODES.hpp send_single_mode): custom_mode from get_px4_custom_mode
(px4_custom_mode.h), standard_mode from mode_util::getStandardModeFromNavState, ADVANCED from
mode_util::isAdvanced, NOT_USER_SELECTABLE when not settable; mode_name only for a non-standard mode: an
external mode's registered name ("(Mode not available)" for a free slot), else mode_util::nav_state_names.
Its update_data bumps a sequence number when the masks change or a registration is answered; from the
first change on, its 0.3 Hz stream sends AVAILABLE_MODES_MONITOR with it (before that: nothing).

The MAVLink simulator registers no external mode (PX4 registers them over uORB/DDS/Zenoh, not MAVLink),
so its slots stay free; ``register``/``unregister`` are where a registration would enter.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..modes import (
    EXTERNAL_MODES,
    FIRST_EXTERNAL_NAV_STATE,
    MODE_PROPERTY_ADVANCED,
    MODE_PROPERTY_NOT_USER_SELECTABLE,
    NAV_STATES,
    PX4_DISPLAY_NAMES,
    encode_custom_mode,
    is_advanced,
    standard_mode_for,
)

NOT_AVAILABLE = "(Mode not available)"   # AVAILABLE_MODES.hpp: a free external slot's mode_name
NAME_LEN = 25                              # register_ext_component_reply_s::name, with its NUL


@dataclass(frozen=True, slots=True)
class ModeEntry:
    """One AVAILABLE_MODES, as PX4 fills it."""
    nav_state: int
    mode: str            # px4_link's name (modes.py)
    custom_mode: int
    standard_mode: int
    properties: int
    mode_name: str       # "" for a standard mode


@dataclass(slots=True)
class _External:
    name: str
    not_user_selectable: bool
    replaces: str | None


class AvailableModes:
    """The list, its registrations and the monitor's sequence number (the simulator's lock guards it)."""

    def __init__(self, rotary_wing: bool = True) -> None:
        self.rotary_wing = rotary_wing
        self._external: dict[int, _External] = {}   # slot n (1..8) -> its registration
        self.seq = 0
        self.changed = False   # PX4's _had_dynamic_update: the monitor is sent from the first change on

    # ---------------------------------------------------------------- registrations
    def register(self, name: str, *, not_user_selectable: bool = False, replaces: str | None = None) -> int:
        """A registered external mode takes the first free slot; its nav_state (23..30). PX4 gives a name its
        earlier slot back (mode_management.py of px4_zenoh does that; here the first free one will do)."""
        for n in range(1, EXTERNAL_MODES + 1):
            if n not in self._external:
                self._external[n] = _External(name[:NAME_LEN - 1], not_user_selectable, replaces)
                self._changed()
                return FIRST_EXTERNAL_NAV_STATE + n - 1
        raise ValueError("all eight external mode slots are taken")

    def unregister(self, nav_state: int) -> None:
        if self._external.pop(nav_state - FIRST_EXTERNAL_NAV_STATE + 1, None) is not None:
            self._changed()

    def _changed(self) -> None:
        self.seq = (self.seq + 1) & 0xFF   # uint8 in AVAILABLE_MODES_MONITOR
        self.changed = True

    # ---------------------------------------------------------------- the list
    def entries(self) -> list[ModeEntry]:
        """Every valid nav state in nav-state order (mode_index = position + 1)."""
        replaced = {e.replaces for e in self._external.values() if e.replaces}
        out = []
        for nav_state, mode in sorted(NAV_STATES.items()):
            standard = standard_mode_for(mode, rotary_wing=self.rotary_wing)
            props = MODE_PROPERTY_ADVANCED if is_advanced(mode) else 0
            name = ""
            ext = self._external.get(nav_state - FIRST_EXTERNAL_NAV_STATE + 1) \
                if nav_state >= FIRST_EXTERNAL_NAV_STATE else None
            if nav_state >= FIRST_EXTERNAL_NAV_STATE:
                selectable = ext is not None
                if ext is None:
                    name = NOT_AVAILABLE
                else:
                    name = ext.name
                    if ext.not_user_selectable:
                        props |= MODE_PROPERTY_NOT_USER_SELECTABLE
            else:
                selectable = mode != "TERMINATION" and mode not in replaced
                if standard == 0:
                    name = PX4_DISPLAY_NAMES[mode]
            if not selectable:
                props |= MODE_PROPERTY_NOT_USER_SELECTABLE
            out.append(ModeEntry(nav_state, mode, encode_custom_mode(mode), standard, props, name))
        return out

    def requested(self, mode_index: int) -> list[ModeEntry] | None:
        """What PX4's request_message sends for param2 = ``mode_index``: all (0), the one asked, or None
        (an index past the list: the request fails, MAV_RESULT_DENIED)."""
        entries = self.entries()
        if mode_index < 0:
            return []   # PX4 finds no such index, sends nothing and still answers ACCEPTED
        if mode_index == 0:
            return entries
        if 1 <= mode_index <= len(entries):
            return [entries[mode_index - 1]]
        return None

    def entry_for(self, mode: str) -> ModeEntry | None:
        return next((e for e in self.entries() if e.mode == mode), None)
