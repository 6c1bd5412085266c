"""MAVLink adapter to PX4 (and a PX4-faithful simulator in ``px4_link.sim``).

Knows nothing of Zenoh: the companion process bridges the two.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from .lazy import lazy_exports

if TYPE_CHECKING:   # loaded on first use (px4_link/lazy.py: a Ctrl-C at start-up)
    from .action import Action, ActionError
    from .commands import (
                           CommandAck,
                           CommandDenied,
                           CommandError,
                           CommandFailed,
                           CommandTemporarilyRejected,
                           CommandTimeout,
                           CommandUnsupported,
                           NotConnected,
    )
    from .link import DEFAULT_CONNECTION, Px4Link
    from .mode_list import AvailableMode, CurrentMode, ModeList
    from .modes import decode_custom_mode, encode_custom_mode, mode_to_main_sub, normalize_mode_name
    from .offboard import Offboard
    from .param import Param, ParamError
    from .stats import LinkStats
    from .targets import Geofence, PositionTarget, Target, TargetRefused, TargetValidator, VehicleMotion, VelocityTarget
    from .telemetry import Attitude, Battery, ExtendedSysState, GlobalPosition, Imu, LocalPosition, Px4State, SysStatus
    from .telemetry_service import Telemetry

__all__ = [
    "Px4Link", "DEFAULT_CONNECTION", "LinkStats", "Px4State", "AvailableMode", "CurrentMode", "ModeList",
    "Action", "ActionError", "Offboard", "Param", "ParamError", "Telemetry",
    "Imu", "Attitude", "LocalPosition", "GlobalPosition", "Battery", "SysStatus",
    "ExtendedSysState",
    "Target", "PositionTarget", "VelocityTarget", "Geofence", "TargetValidator", "TargetRefused",
    "VehicleMotion",
    "CommandAck", "CommandError", "CommandDenied", "CommandTemporarilyRejected",
    "CommandUnsupported", "CommandFailed", "CommandTimeout", "NotConnected",
    "decode_custom_mode", "encode_custom_mode", "mode_to_main_sub", "normalize_mode_name",
]

__getattr__ = lazy_exports(__name__, {
    ".action": ("Action", "ActionError"),
    ".commands": ("CommandAck", "CommandDenied", "CommandError", "CommandFailed", "CommandTemporarilyRejected",
                  "CommandTimeout", "CommandUnsupported", "NotConnected"),
    ".link": ("DEFAULT_CONNECTION", "Px4Link"),
    ".mode_list": ("AvailableMode", "CurrentMode", "ModeList"),
    ".modes": ("decode_custom_mode", "encode_custom_mode", "mode_to_main_sub", "normalize_mode_name"),
    ".offboard": ("Offboard",),
    ".param": ("Param", "ParamError"),
    ".stats": ("LinkStats",),
    ".targets": ("Geofence", "PositionTarget", "Target", "TargetRefused", "TargetValidator", "VehicleMotion",
                 "VelocityTarget"),
    ".telemetry": ("Attitude", "Battery", "ExtendedSysState", "GlobalPosition", "Imu", "LocalPosition", "Px4State",
                   "SysStatus"),
    ".telemetry_service": ("Telemetry",),
})
