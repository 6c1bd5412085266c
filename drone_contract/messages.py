"""Messages between a GCS and a drone's companion: vehicle state, commands, setpoints, events.

Who is talking: every Command and every DroneSetpoint carries the sender's ``client_id``
(a GCS id, ``user@host`` by default). The companion obeys only the GCS holding control
(see companion/control.py). The id is a claim, not a proof: any peer on the Zenoh network
can forge it unless the secure profile is on (TLS with client certificates and an ACL
that lets only GCS identities publish on ``<id>/setpoint`` and query ``<id>/command``).
"""
from __future__ import annotations

import re

from zenoh_robot.message import Message, array, message, ros_field
from zenoh_robot.msgs import Header

# Also a Zenoh key chunk (the GCS's liveliness token): no '/', '*', '$', '?', '#'.
CLIENT_ID = re.compile(r"^[A-Za-z0-9_.@:+-]{1,64}$")
CONTROL_TOKEN_PREFIX = "zr_gcs"   # <prefix>/<client_id>: a GCS's liveliness token


def valid_client_id(client_id: str) -> bool:
    return bool(CLIENT_ID.match(client_id))


@message(name="zenoh_robot/VehicleState")
class VehicleState(Message):
    header: Header = None  # type: ignore[assignment]
    mode: str = ""                   # PX4 mode name: OFFBOARD, AUTO.LOITER, ...
    armed: bool = False
    landed: bool = True
    connected: bool = False          # PX4 heartbeats seen within the timeout
    offboard_streaming: bool = False
    position: list[float] = array("float32", 3, default=[0.0, 0.0, 0.0])      # local NED, m
    velocity: list[float] = array("float32", 3, default=[0.0, 0.0, 0.0])      # m/s
    attitude: list[float] = array("float32", 3, default=[0.0, 0.0, 0.0])      # roll, pitch, yaw, rad
    battery_remaining: float = ros_field("float32", default=float("nan"))  # 0..1
    battery_voltage: float = ros_field("float32", default=float("nan"))
    failsafe: str = ""               # "" or why the companion holds (e.g. "setpoint deadline missed")
    setpoints_rejected: int = 0
    offboard_state: str = ""         # the companion's offboard lifecycle: idle, starting, active, failsafe_hold
    controller: str = ""             # client_id of the GCS in control, "" when none
    sensor_rate_hz: float = ros_field("float32", default=float("nan"))            # HIGHRES_IMU rate PX4 delivers
    sensor_rate_requested_hz: float = ros_field("float32", default=float("nan"))  # what the companion asked
    commands_refused: int = 0
    armable: bool = False            # PX4's pre-arm checks pass (SYS_STATUS PREARM_CHECK health bit)
    link_refused: int = 0            # sealed samples and calls refused (forged, replayed, not fresh): an attack shows
    mode_name: str = ""              # an external mode's registered name ("" for PX4's own modes): QGC shows it too
    session_mode: str = ""           # the mode offboard_start flies in: OFFBOARD, or the companion's external mode

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()

    @property
    def in_session_mode(self) -> bool:
        """PX4 flies the mode the companion's offboard session flies in (OFFBOARD, or its external mode; a
        companion older than ``session_mode`` flies OFFBOARD)."""
        return self.mode == (self.session_mode or "OFFBOARD")

    @property
    def mode_label(self) -> str:
        """The mode as an operator reads it: an external mode by its registered name, as QGC shows it."""
        return f"{self.mode_name} ({self.mode})" if self.mode_name else self.mode


@message(name="zenoh_robot/Command")
class Command(Message):
    """A request to a drone: name (arm, disarm, takeoff, land, hold, rtl, offboard_start,
    offboard_stop, set_param, take_control, release_control) and its arguments."""
    name: str = ""
    value: float = 0.0               # takeoff altitude, parameter value
    text: str = ""                   # parameter name
    force: bool = False              # disarm: in flight; take_control: take over from another GCS
    client_id: str = ""              # who asks (see the module docstring: forgeable without ACLs)


@message(name="zenoh_robot/CommandResult")
class CommandResult(Message):
    success: bool = False
    message: str = ""
    mode: str = ""                   # vehicle mode after the command


@message(name="zenoh_robot/DroneSetpoint")
class DroneSetpoint(Message):
    """A position (local NED, m) or velocity (m/s) target from one GCS."""
    header: Header = None  # type: ignore[assignment]
    client_id: str = ""
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = float("nan")        # rad; NaN leaves the heading to PX4
    is_velocity: bool = False

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@message(name="zenoh_robot/FailsafeEvent")
class FailsafeEvent(Message):
    """What the companion saw and did. Kinds: setpoint_deadline_missed, offboard_lost,
    setpoint_rejected, control_refused, control_changed, lifecycle, sensor_rate_low,
    px4_reconnected, failsafe_failed, stray_offboard."""
    header: Header = None  # type: ignore[assignment]
    kind: str = ""
    detail: str = ""
    action: str = ""                 # what the companion did: HOLD, none, ...
    client_id: str = ""              # whom it concerns (the refused sender), "" for everyone
    count: int = 0                   # for rate-limited kinds: how many so far

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@message(name="zenoh_robot/GcsPresence")
class GcsPresence(Message):
    """A GCS saying it still runs, at a low rate, to each drone it controls: the companion renews
    the holder's lease by it where the GCS's liveliness token cannot reach (a UDP multicast session)."""
    header: Header = None  # type: ignore[assignment]
    client_id: str = ""

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


# A mission fails when one of these reaches it (setpoint_rejected only when addressed to it).
FAILSAFE_KINDS = ("setpoint_deadline_missed", "offboard_lost", "failsafe_failed", "control_lost")
