"""The PX4 topics the backend uses, and their keys as PX4 announces them.

A PX4 key is ``<ZENOH_DOMAIN_ID>/fmu/<in|out>/<topic>/px4_msgs::msg::dds_::<Type>_/RIHS01_<hash>``.
The hash is computed at PX4's build from PX4's own ``.msg`` files, so it is never hard-coded here:
``KeyBook`` learns each key from PX4's liveliness tokens (``@ros2_lv/<domain>/<zid>/0/11/<MP|MS>/
%/%/px4_<guid>/%fmu%out%<topic>/<dds type>/RIHS01_<hash>/<qos>``) and compares the hash with ours.
A mismatch is named (topic, type, both hashes): PX4 would silently ignore our samples and we would
fail to decode its, so the backend refuses that topic and says why.

Type names follow the message type, not the topic (``vehicle_gps_position`` carries ``SensorGps``).
Some of PX4's default ``/fmu/in`` topics map to the wrong uORB topic in this PX4 (odometry,
config_control_setpoints): they are not in the table, so nothing is ever published there.

Threading: a ``KeyBook`` is guarded by its own lock (tokens arrive on Zenoh's threads).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

from zenoh_robot.wire.ros2 import Ros2Token, parse_any_token

PX4_NODE_PREFIX = "px4_"
OUT, IN = "out", "in"


@dataclass(frozen=True)
class Px4Topic:
    name: str          # "/fmu/out/vehicle_status"
    type_short: str    # "VehicleStatus"

    @property
    def direction(self) -> str:
        return OUT if self.name.startswith("/fmu/out/") else IN

    @property
    def type_name(self) -> str:
        return f"px4_msgs/msg/{self.type_short}"

    @property
    def dds_type(self) -> str:
        return f"px4_msgs::msg::dds_::{self.type_short}_"

    def key(self, domain: int, type_hash: str) -> str:
        return f"{domain}{self.name}/{self.dds_type}/{type_hash}"

    def any_hash_key(self, domain: int) -> str:
        return f"{domain}{self.name}/{self.dds_type}/*"


def _t(name: str, short: str) -> Px4Topic:
    return Px4Topic(name, short)


# What the companion reads from PX4 (rates as PX4 SITL sent them on the ground, px4_zenoh_traces).
VEHICLE_STATUS = _t("/fmu/out/vehicle_status", "VehicleStatus")                     # 2 Hz + every change
COMMAND_ACK = _t("/fmu/out/vehicle_command_ack", "VehicleCommandAck")                # events
FAILSAFE_FLAGS = _t("/fmu/out/failsafe_flags", "FailsafeFlags")                      # 2 Hz
LAND_DETECTED = _t("/fmu/out/vehicle_land_detected", "VehicleLandDetected")          # 1 Hz + changes
LOCAL_POSITION = _t("/fmu/out/vehicle_local_position", "VehicleLocalPosition")       # 124 Hz
GLOBAL_POSITION = _t("/fmu/out/vehicle_global_position", "VehicleGlobalPosition")    # 124 Hz
ATTITUDE = _t("/fmu/out/vehicle_attitude", "VehicleAttitude")                        # 248 Hz
SENSOR_COMBINED = _t("/fmu/out/sensor_combined", "SensorCombined")                   # 248 Hz
BATTERY = _t("/fmu/out/battery_status", "BatteryStatus")                             # 99 Hz
GPS = _t("/fmu/out/vehicle_gps_position", "SensorGps")                               # 8 Hz
CONTROL_MODE = _t("/fmu/out/vehicle_control_mode", "VehicleControlMode")             # 2 Hz
# What the companion sends to PX4.
OFFBOARD_MODE = _t("/fmu/in/offboard_control_mode", "OffboardControlMode")
TRAJECTORY = _t("/fmu/in/trajectory_setpoint", "TrajectorySetpoint")
VEHICLE_COMMAND = _t("/fmu/in/vehicle_command", "VehicleCommand")

# External modes (px4_zenoh.external_mode; PX4's commander/ModeManagement.cpp on the other side).
REGISTER_REQUEST = _t("/fmu/in/register_ext_component_request", "RegisterExtComponentRequest")
REGISTER_REPLY = _t("/fmu/out/register_ext_component_reply", "RegisterExtComponentReply")
UNREGISTER = _t("/fmu/in/unregister_ext_component", "UnregisterExtComponent")
CHECK_REQUEST = _t("/fmu/out/arming_check_request", "ArmingCheckRequest")      # every 300 ms
CHECK_REPLY = _t("/fmu/in/arming_check_reply", "ArmingCheckReply")
MODE_COMPLETED_IN = _t("/fmu/in/mode_completed", "ModeCompleted")
MODE_COMPLETED_OUT = _t("/fmu/out/mode_completed", "ModeCompleted")
GOTO = _t("/fmu/in/goto_setpoint", "GotoSetpoint")
# PX4 main 2026-03's zenoh module maps these onto the wrong uORB topic (the default topic of their type:
# vehicle_control_mode, config_overrides, vehicle_command; fixed by PX4 PR #26564). Never sent by this
# package while that PX4 may be on the other side (external_mode.BridgeBug).
CONFIG_CONTROL_SETPOINTS = _t("/fmu/in/config_control_setpoints", "VehicleControlMode")
CONFIG_OVERRIDES_REQUEST = _t("/fmu/in/config_overrides_request", "ConfigOverrides")
COMMAND_MODE_EXECUTOR = _t("/fmu/in/vehicle_command_mode_executor", "VehicleCommand")
EXTERNAL_MODE_TOPICS: tuple[Px4Topic, ...] = (REGISTER_REQUEST, REGISTER_REPLY, UNREGISTER, CHECK_REQUEST,
                                              CHECK_REPLY, MODE_COMPLETED_IN, MODE_COMPLETED_OUT, GOTO)
MISROUTED: tuple[Px4Topic, ...] = (CONFIG_CONTROL_SETPOINTS, CONFIG_OVERRIDES_REQUEST, COMMAND_MODE_EXECUTOR)

USED: tuple[Px4Topic, ...] = (VEHICLE_STATUS, COMMAND_ACK, FAILSAFE_FLAGS, LAND_DETECTED, LOCAL_POSITION,
                              GLOBAL_POSITION, ATTITUDE, SENSOR_COMBINED, BATTERY, GPS, CONTROL_MODE,
                              OFFBOARD_MODE, TRAJECTORY, VEHICLE_COMMAND)
BY_NAME = {t.name: t for t in USED}


def token_pattern(domain: int) -> str:
    """Every entity token of a PX4 in ``domain`` (PX4 declares its node in domain 0 whatever
    ZENOH_DOMAIN_ID says, its entities in ZENOH_DOMAIN_ID)."""
    return f"@ros2_lv/{domain}/**"


@dataclass(frozen=True)
class HashMismatch:
    topic: str
    type_name: str
    theirs: str
    ours: str

    def __str__(self) -> str:
        return (f"PX4 announces {self.topic} as {self.type_name} {self.theirs}, our definition hashes to "
                f"{self.ours}: px4_msgs of another PX4 version; pass --px4-msgs <PX4 tree>/msg")


class KeyBook:
    """The keys of the used topics, as PX4's tokens announce them."""

    def __init__(self, domain: int, our_hashes: dict[str, str], topics: tuple[Px4Topic, ...] = USED) -> None:
        self.domain = domain
        self._by_name = {t.name: t for t in topics}
        self._ours = our_hashes            # type name (px4_msgs/msg/X) -> RIHS01_...
        self._keys: dict[str, str] = {}    # topic -> key
        self._mismatch: dict[str, HashMismatch] = {}
        self._lock = threading.Lock()

    def learn(self, token_key: str) -> HashMismatch | None:
        """Take one liveliness token; return a new mismatch if this token shows one. Tokens of other
        nodes, of unused topics, or unparsable, are ignored (PX4's tokens are the only authority)."""
        try:
            tok: Ros2Token = parse_any_token(token_key)
        except ValueError:
            return None
        if not tok.node.startswith(PX4_NODE_PREFIX) or tok.domain_id != self.domain:
            return None
        topic = self._by_name.get(tok.name)
        if topic is None or tok.raw_type != topic.dds_type:
            return None
        want = "MP" if topic.direction == OUT else "MS"
        if tok.kind != want:
            return None
        ours = self._ours.get(topic.type_name, "")
        with self._lock:
            if tok.type_hash != ours:
                if topic.name in self._mismatch:
                    return None
                mm = self._mismatch[topic.name] = HashMismatch(topic.name, topic.type_name, tok.type_hash, ours)
                self._keys.pop(topic.name, None)
                return mm
            self._mismatch.pop(topic.name, None)
            self._keys[topic.name] = topic.key(self.domain, tok.type_hash)
            return None

    def key(self, topic: Px4Topic) -> str | None:
        with self._lock:
            return self._keys.get(topic.name)

    def mismatches(self) -> list[HashMismatch]:
        with self._lock:
            return list(self._mismatch.values())

    def known(self) -> dict[str, str]:
        with self._lock:
            return dict(self._keys)
