"""PX4 flight modes <-> MAVLink HEARTBEAT ``custom_mode``.

PX4 packs its mode into the 32-bit ``custom_mode`` as
``(main_mode << 16) | (sub_mode << 24)`` (px4_custom_mode.h): byte 2 is the main mode,
byte 3 the sub mode (only AUTO and POSCTL have sub modes). Names follow the strings
MAVROS and QGroundControl use ("AUTO.LOITER", "OFFBOARD", ...), so logs read the same.
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
