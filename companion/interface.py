"""Messages between a GCS and a drone's companion: vehicle state, commands, failsafe events."""
from __future__ import annotations

from zenoh_robot.message import Message, array, message, ros_field
from zenoh_robot.msgs import Header


@message(name="zenoh_robot/VehicleState")
class VehicleState(Message):
    header: Header = None  # type: ignore[assignment]
    mode: str = ""                   # PX4 mode name: OFFBOARD, AUTO.LOITER, ...
    armed: bool = False
    landed: bool = True
    connected: bool = False          # PX4 heartbeats seen within the timeout
    offboard_streaming: bool = False
    position: list[float] = array("float32", 3)      # local NED, m
    velocity: list[float] = array("float32", 3)      # m/s
    attitude: list[float] = array("float32", 3)      # roll, pitch, yaw, rad
    battery_remaining: float = ros_field("float32", float("nan"))  # 0..1
    battery_voltage: float = ros_field("float32", float("nan"))
    failsafe: str = ""               # "" or why the companion holds (e.g. "setpoint deadline missed")
    setpoints_rejected: int = 0

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@message(name="zenoh_robot/Command")
class Command(Message):
    """A request to a drone: name (arm, disarm, takeoff, land, hold, rtl, offboard_start,
    offboard_stop, set_param) and its arguments."""
    name: str = ""
    value: float = 0.0               # takeoff altitude, parameter value
    text: str = ""                   # parameter name
    force: bool = False


@message(name="zenoh_robot/CommandResult")
class CommandResult(Message):
    success: bool = False
    message: str = ""
    mode: str = ""                   # vehicle mode after the command


@message(name="zenoh_robot/FailsafeEvent")
class FailsafeEvent(Message):
    header: Header = None  # type: ignore[assignment]
    kind: str = ""                   # setpoint_deadline_missed, setpoints_resumed, px4_disconnected, ...
    detail: str = ""
    action: str = ""                 # what the companion did: HOLD, none, ...

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()
