"""PX4 flight modes <-> MAVLink HEARTBEAT ``custom_mode``.

PX4 packs its mode into the 32-bit ``custom_mode`` as
``(main_mode << 16) | (sub_mode << 24)`` (px4_custom_mode.h): byte 2 is the main mode,
byte 3 the sub mode (only AUTO and POSCTL have sub modes). Names follow the strings
MAVROS and QGroundControl use ("AUTO.LOITER", "OFFBOARD", ...), so logs read the same.

External modes (a companion's, registered with PX4 since v1.15) are AUTO sub modes 11..18
(PX4_CUSTOM_SUB_MODE_EXTERNAL1..8, nav_state 23..30): ``EXTERNAL<n>`` here, as px4_zenoh names
nav_state 22+n; their registered names come from AVAILABLE_MODES (mode_list.py).
"""
from __future__ import annotations

# Main modes (PX4_CUSTOM_MAIN_MODE_*).
MAIN_MANUAL = 1
MAIN_ALTCTL = 2
MAIN_POSCTL = 3
MAIN_AUTO = 4
MAIN_ACRO = 5
MAIN_OFFBOARD = 6
MAIN_STABILIZED = 7
MAIN_RATTITUDE = 8  # removed from recent PX4, still decoded for old logs/vehicles
MAIN_TERMINATION = 10
MAIN_ALTITUDE_CRUISE = 11

# AUTO sub modes (PX4_CUSTOM_SUB_MODE_AUTO_*); 7 (RTGS) was removed from PX4.
SUB_AUTO_READY = 1
SUB_AUTO_TAKEOFF = 2
SUB_AUTO_LOITER = 3
SUB_AUTO_MISSION = 4
SUB_AUTO_RTL = 5
SUB_AUTO_LAND = 6
SUB_AUTO_FOLLOW_TARGET = 8
SUB_AUTO_PRECLAND = 9
SUB_AUTO_VTOL_TAKEOFF = 10
SUB_AUTO_EXTERNAL1 = 11       # PX4_CUSTOM_SUB_MODE_EXTERNAL1; EXTERNAL8 is 18
EXTERNAL_MODES = 8            # NAVIGATION_STATE_EXTERNAL1..8 (23..30)
FIRST_EXTERNAL_NAV_STATE = 23

# POSCTL sub modes.
SUB_POSCTL_POSCTL = 0
SUB_POSCTL_ORBIT = 1
SUB_POSCTL_SLOW = 2

_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (MAIN_MANUAL, 0),
    "ALTCTL": (MAIN_ALTCTL, 0),
    "POSCTL": (MAIN_POSCTL, SUB_POSCTL_POSCTL),
    "POSCTL.ORBIT": (MAIN_POSCTL, SUB_POSCTL_ORBIT),
    "POSCTL.SLOW": (MAIN_POSCTL, SUB_POSCTL_SLOW),
    "AUTO.READY": (MAIN_AUTO, SUB_AUTO_READY),
    "AUTO.TAKEOFF": (MAIN_AUTO, SUB_AUTO_TAKEOFF),
    "AUTO.LOITER": (MAIN_AUTO, SUB_AUTO_LOITER),
    "AUTO.MISSION": (MAIN_AUTO, SUB_AUTO_MISSION),
    "AUTO.RTL": (MAIN_AUTO, SUB_AUTO_RTL),
    "AUTO.LAND": (MAIN_AUTO, SUB_AUTO_LAND),
    "AUTO.FOLLOW_TARGET": (MAIN_AUTO, SUB_AUTO_FOLLOW_TARGET),
    "AUTO.PRECLAND": (MAIN_AUTO, SUB_AUTO_PRECLAND),
    "AUTO.VTOL_TAKEOFF": (MAIN_AUTO, SUB_AUTO_VTOL_TAKEOFF),
    "ACRO": (MAIN_ACRO, 0),
    "OFFBOARD": (MAIN_OFFBOARD, 0),
    "STABILIZED": (MAIN_STABILIZED, 0),
    "RATTITUDE": (MAIN_RATTITUDE, 0),
    "TERMINATION": (MAIN_TERMINATION, 0),
    "ALTITUDE_CRUISE": (MAIN_ALTITUDE_CRUISE, 0),
    **{f"EXTERNAL{n}": (MAIN_AUTO, SUB_AUTO_EXTERNAL1 + n - 1) for n in range(1, EXTERNAL_MODES + 1)},
}
_BY_CODE: dict[tuple[int, int], str] = {code: name for name, code in _MODES.items()}

# Friendly names users (and the issue) use for the same modes.
ALIASES: dict[str, str] = {
    "HOLD": "AUTO.LOITER",
    "LOITER": "AUTO.LOITER",
    "LAND": "AUTO.LAND",
    "RTL": "AUTO.RTL",
    "RETURN": "AUTO.RTL",
    "TAKEOFF": "AUTO.TAKEOFF",
    "MISSION": "AUTO.MISSION",
    "POSITION": "POSCTL",
    "ALTITUDE": "ALTCTL",
    "STABILIZE": "STABILIZED",
}

MODE_NAMES: tuple[str, ...] = tuple(_MODES)


class UnknownModeError(ValueError):
    """A mode name this module cannot encode."""


def normalize_mode_name(name: str) -> str:
    """Canonical PX4 mode name for ``name`` or an alias (case-insensitive)."""
    key = name.strip().upper()
    key = ALIASES.get(key, key)
    if key not in _MODES:
        raise UnknownModeError(f"unknown PX4 mode {name!r}; known: {', '.join(MODE_NAMES)} "
                               f"and aliases {', '.join(ALIASES)}")
    return key


def mode_to_main_sub(name: str) -> tuple[int, int]:
    """(main_mode, sub_mode) as MAV_CMD_DO_SET_MODE wants them in param2/param3."""
    return _MODES[normalize_mode_name(name)]


def encode_custom_mode(name: str) -> int:
    """HEARTBEAT custom_mode for a mode name, e.g. OFFBOARD -> 6 << 16."""
    main, sub = mode_to_main_sub(name)
    return (main << 16) | (sub << 24)


def decode_main_sub(main: int, sub: int) -> str:
    """Mode name for a (main, sub) pair; unknown pairs get a readable placeholder."""
    name = _BY_CODE.get((main, sub))
    if name is None and main != MAIN_AUTO and main != MAIN_POSCTL:
        # Sub mode is meaningless outside AUTO/POSCTL; PX4 leaves it 0 but be lenient.
        name = _BY_CODE.get((main, 0))
    return name if name is not None else f"UNKNOWN({main}.{sub})"


def decode_custom_mode(custom_mode: int) -> str:
    """Mode name from a PX4 HEARTBEAT custom_mode."""
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    return decode_main_sub(main, sub)


def external_mode_number(custom_mode: int) -> int | None:
    """n (1..8) when ``custom_mode`` is PX4's external mode n, ((10+n) << 24) | (4 << 16); else None."""
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    n = sub - SUB_AUTO_EXTERNAL1 + 1
    return n if main == MAIN_AUTO and 1 <= n <= EXTERNAL_MODES else None


# PX4's nav states (VehicleStatus.msg NAVIGATION_STATE_*) by the names above: what the simulator lists in
# AVAILABLE_MODES, in nav-state order as PX4 does. Those of mode_util::getValidNavStates() (lib/modes/ui.hpp)
# plus the eight external slots ModeManagement::getModeStatus adds; DESCEND (12) is not among them.
NAV_STATES: dict[int, str] = {
    0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO.MISSION", 4: "AUTO.LOITER", 5: "AUTO.RTL",
    6: "POSCTL.SLOW", 8: "ALTITUDE_CRUISE", 10: "ACRO", 13: "TERMINATION", 14: "OFFBOARD", 15: "STABILIZED",
    17: "AUTO.TAKEOFF", 18: "AUTO.LAND", 19: "AUTO.FOLLOW_TARGET", 20: "AUTO.PRECLAND", 21: "POSCTL.ORBIT",
    22: "AUTO.VTOL_TAKEOFF",
    **{FIRST_EXTERNAL_NAV_STATE + n - 1: f"EXTERNAL{n}" for n in range(1, EXTERNAL_MODES + 1)},
}
# mode_util::nav_state_names (lib/modes/ui.hpp): the mode_name PX4 puts in AVAILABLE_MODES for an internal mode
# that has no standard mode.
PX4_DISPLAY_NAMES: dict[str, str] = {
    "MANUAL": "Manual", "ALTCTL": "Altitude", "POSCTL": "Position", "AUTO.MISSION": "Mission",
    "AUTO.LOITER": "Hold", "AUTO.RTL": "Return", "POSCTL.SLOW": "Position Slow",
    "ALTITUDE_CRUISE": "Altitude Cruise", "ACRO": "Acro", "TERMINATION": "Termination",
    "OFFBOARD": "Offboard", "STABILIZED": "Stabilized", "AUTO.TAKEOFF": "Takeoff", "AUTO.LAND": "Land",
    "AUTO.FOLLOW_TARGET": "Follow Target", "AUTO.PRECLAND": "Precision Landing", "POSCTL.ORBIT": "Orbit",
    "AUTO.VTOL_TAKEOFF": "VTOL Takeoff",
}

# MAV_STANDARD_MODE (development.xml), the values of PX4's mode_util::StandardMode.
STANDARD_MODE_NAMES: dict[int, str] = {
    0: "NON_STANDARD", 1: "POSITION_HOLD", 2: "ORBIT", 3: "CRUISE", 4: "ALTITUDE_HOLD", 5: "SAFE_RECOVERY",
    6: "MISSION", 7: "LAND", 8: "TAKEOFF",
}
# MAV_MODE_PROPERTY bits of AVAILABLE_MODES.properties.
MODE_PROPERTY_ADVANCED = 1
MODE_PROPERTY_NOT_USER_SELECTABLE = 2


def standard_mode_for(name: str, rotary_wing: bool = True, vtol: bool = False) -> int:
    """PX4's mode_util::getStandardModeFromNavState (lib/modes/standard_modes.hpp) for a multicopter
    (``rotary_wing``) or a fixed wing; 0 (NON_STANDARD) for every mode it does not map."""
    fixed_wing = not rotary_wing
    if name == "AUTO.RTL":
        return 5
    if name == "AUTO.MISSION":
        return 6
    if name == "AUTO.LAND":
        return 7
    if name == "AUTO.TAKEOFF":
        return 8
    if name == "ALTCTL":
        return 4   # every vehicle type PX4 flies with it (rotary, fixed wing, VTOL)
    if name == "POSCTL" and not vtol:
        return 1 if rotary_wing else 3 if fixed_wing else 0
    if name == "POSCTL.ORBIT":
        return 2
    return 0


def is_advanced(name: str) -> bool:
    """mode_util::isAdvanced (lib/modes/ui.hpp): QGC hides advanced modes from a basic user's list."""
    return not (name in ("ALTCTL", "POSCTL") or name.startswith("EXTERNAL"))
