"""MAVLink adapter to PX4 (and a PX4-faithful simulator in ``px4_link.sim``).

Knows nothing of Zenoh: the companion process bridges the two.
"""
from .commands import (CommandAck, CommandDenied, CommandError, CommandFailed,
                       CommandTemporarilyRejected, CommandTimeout, CommandUnsupported, NotConnected)
from .link import Px4Link
from .modes import decode_custom_mode, encode_custom_mode, mode_to_main_sub, normalize_mode_name
from .setpoints import Geofence, PositionSetpoint, SetpointRejected, VelocitySetpoint
from .stats import LinkStats
from .telemetry import (Attitude, Battery, ExtendedSysState, GlobalPosition, Imu, LocalPosition,
                        SysStatus, VehicleState)

__all__ = [
    "Px4Link", "LinkStats", "VehicleState",
    "Imu", "Attitude", "LocalPosition", "GlobalPosition", "Battery", "SysStatus",
    "ExtendedSysState",
    "PositionSetpoint", "VelocitySetpoint", "Geofence", "SetpointRejected",
    "CommandAck", "CommandError", "CommandDenied", "CommandTemporarilyRejected",
    "CommandUnsupported", "CommandFailed", "CommandTimeout", "NotConnected",
    "decode_custom_mode", "encode_custom_mode", "mode_to_main_sub", "normalize_mode_name",
]
