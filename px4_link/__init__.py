"""MAVLink adapter to PX4 (and a PX4-faithful simulator in ``px4_link.sim``).

Knows nothing of Zenoh: the companion process bridges the two.
"""
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
from .modes import decode_custom_mode, encode_custom_mode, mode_to_main_sub, normalize_mode_name
from .offboard import Offboard, OffboardError
from .param import Param, ParamError
from .setpoints import Geofence, OffboardSetpoint, PositionSetpoint, Setpoint, SetpointRejected, VelocitySetpoint
from .stats import LinkStats
from .telemetry import (
                       Attitude,
                       Battery,
                       ExtendedSysState,
                       GlobalPosition,
                       Imu,
                       LocalPosition,
                       Px4State,
                       SysStatus,
                       VehicleState,
)
from .telemetry_service import Telemetry

__all__ = [
    "Px4Link", "DEFAULT_CONNECTION", "LinkStats", "Px4State", "VehicleState",
    "Action", "ActionError", "Offboard", "OffboardError", "Param", "ParamError", "Telemetry",
    "Imu", "Attitude", "LocalPosition", "GlobalPosition", "Battery", "SysStatus",
    "ExtendedSysState",
    "OffboardSetpoint", "Setpoint", "PositionSetpoint", "VelocitySetpoint", "Geofence",
    "SetpointRejected",
    "CommandAck", "CommandError", "CommandDenied", "CommandTemporarilyRejected",
    "CommandUnsupported", "CommandFailed", "CommandTimeout", "NotConnected",
    "decode_custom_mode", "encode_custom_mode", "mode_to_main_sub", "normalize_mode_name",
]
