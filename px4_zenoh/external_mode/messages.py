"""The uORB messages of PX4's external-mode protocol, built as PX4's commander reads them.

One job: turn what a mode says (its name, its check's verdict and reasons, its setpoints) into the px4_msgs
values of PX4 main 2026-03 (msg/versioned/RegisterExtComponentRequest.msg, ArmingCheckReply.msg, ...), and
back. No Zenoh here (``mode.py`` sends them).

- names are ``char[25]``: at most 24 UTF-8 bytes, NUL-padded (PX4 forces the 25th to NUL).
- a reason travels as a PX4 ``Event`` in the reply (at most 5): PX4 overwrites the first 4 argument bytes
  with the mode mask (externalChecks.cpp checkAndReport), so the text sits in bytes 4..24 (21 bytes); the id
  is the FNV-1a hash of the full text, so a GCS or a log can tell reasons apart even when cut. PX4 forwards
  the event to a GCS as MAVLink EVENT; QGC shows the text only with matching event metadata, which this
  component does not publish: the text is for this project's own tools, logs and the simulator.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

NAME_BYTES = 24
MAX_EVENTS = 5
EVENT_TEXT_BYTES = 21
LOG_LEVEL_ERROR = 0x33           # external and internal log level 3 (error)
API_VERSION = 1                  # RegisterExtComponentRequest LATEST_PX4_ROS2_API_VERSION
CMD_SET_NAV_STATE = 100001       # VehicleCommand VEHICLE_CMD_SET_NAV_STATE
CMD_NAV_TAKEOFF = 22             # VehicleCommand VEHICLE_CMD_NAV_TAKEOFF
CMD_ARM_DISARM = 400             # VehicleCommand VEHICLE_CMD_COMPONENT_ARM_DISARM
COMPONENT_MODE_EXECUTOR_START = 1000   # VehicleCommand COMPONENT_MODE_EXECUTOR_START
ARMING_STATE_ARMED = 2
RESULT_SUCCESS, RESULT_FAILURE_OTHER = 0, 100        # ModeCompleted RESULT_*
SOURCE_TYPE_MODE = 0                                 # ConfigOverrides SOURCE_TYPE_MODE
# The internal modes a component may replace, by the names a user gives (VehicleStatus NAVIGATION_STATE_*).
INTERNAL_MODES = {"hold": 4, "loiter": 4, "rtl": 5, "mission": 3, "takeoff": 17, "land": 18, "precland": 20}
NAN3 = [math.nan] * 3


def fnv1a_32(text: str) -> int:
    h = 0x811C9DC5
    for b in text.encode():
        h = ((h ^ b) * 0x01000193) & 0xFFFFFFFF
    return h


def encode_name(name: str) -> bytes:
    raw = name.encode()
    if not raw or len(raw) > NAME_BYTES or b"\0" in raw:
        raise ValueError(f"mode name {name!r}: 1..{NAME_BYTES} UTF-8 bytes, no NUL (PX4's char[25])")
    return raw.ljust(NAME_BYTES + 1, b"\0")


def decode_name(raw: bytes) -> str:
    return bytes(raw[:NAME_BYTES]).split(b"\0", 1)[0].decode("utf-8", "replace")


def internal_mode(spec: str | int | None) -> int | None:
    """``"rtl"`` / ``5`` -> nav_state 5; None -> None (no replacement)."""
    if spec is None or isinstance(spec, int):
        return spec
    try:
        return INTERNAL_MODES[spec.lower()]
    except KeyError:
        raise ValueError(f"cannot replace {spec!r}: one of {', '.join(sorted(INTERNAL_MODES))}") from None


def event_for(types: dict[str, Any], reason: str) -> Any:
    text = reason.encode()[:EVENT_TEXT_BYTES]
    return types["Event"](timestamp=0, id=fnv1a_32(reason), event_sequence=0,
                          arguments=(bytes(4) + text).ljust(25, b"\0"), log_levels=LOG_LEVEL_ERROR)


def event_text(event: Any) -> str:
    return bytes(event.arguments[4:]).split(b"\0", 1)[0].decode("utf-8", "replace")


def register_request(types: dict[str, Any], name: str, request_id: int, replace: int | None,
                     executor: bool = False) -> Any:
    """A mode with its arming check; with ``executor`` the mode's executor too, in the same request (as
    px4-ros2's ModeExecutorBase::doRegister: the executor owns that mode)."""
    return types["RegisterExtComponentRequest"](
        timestamp=0, request_id=request_id, name=encode_name(name), px4_ros2_api_version=API_VERSION,
        register_arming_check=True, register_mode=True, register_mode_executor=executor,
        enable_replace_internal_mode=replace is not None, replace_internal_mode=replace or 0,
        activate_mode_immediately=False, not_user_selectable=False)


def unregister(types: dict[str, Any], name: str, arming_check_id: int, mode_id: int,
               mode_executor_id: int = -1) -> Any:
    return types["UnregisterExtComponent"](timestamp=0, name=encode_name(name), arming_check_id=arming_check_id,
                                           mode_id=mode_id, mode_executor_id=mode_executor_id)


def check_reply(types: dict[str, Any], request_id: int, registration_id: int, can_arm_and_run: bool,
                reasons: Sequence[str], requires_position: bool) -> Any:
    """ArmingCheckReply; the requirements px4-ros2 sets for a position-controlled mode when asked to."""
    events = [event_for(types, r) for r in list(reasons)[:MAX_EVENTS]]
    n = len(events)
    events += [types["Event"]() for _ in range(MAX_EVENTS - n)]
    return types["ArmingCheckReply"](
        timestamp=0, request_id=request_id, registration_id=registration_id, health_component_index=0,
        health_component_is_present=False, health_component_warning=False, health_component_error=False,
        can_arm_and_run=can_arm_and_run, num_events=n, events=events, mode_req_angular_velocity=True,
        mode_req_attitude=True, mode_req_local_alt=requires_position, mode_req_local_position=requires_position,
        mode_req_local_position_relaxed=False, mode_req_global_position=False,
        mode_req_global_position_relaxed=False, mode_req_mission=False, mode_req_home_position=False,
        mode_req_prevent_arming=False, mode_req_manual_control=False)


def trajectory(types: dict[str, Any], position: Sequence[float] | None, velocity: Sequence[float] | None,
               yaw: float | None) -> Any:
    return types["TrajectorySetpoint"](
        timestamp=0, position=list(position) if position is not None else NAN3,
        velocity=list(velocity) if velocity is not None else NAN3, acceleration=NAN3, jerk=NAN3,
        yaw=math.nan if yaw is None else yaw, yawspeed=math.nan)


def goto(types: dict[str, Any], position: Sequence[float], heading: float | None) -> Any:
    return types["GotoSetpoint"](
        timestamp=0, position=list(position), flag_control_heading=heading is not None,
        heading=math.nan if heading is None else heading, flag_set_max_horizontal_speed=False,
        max_horizontal_speed=math.nan, flag_set_max_vertical_speed=False, max_vertical_speed=math.nan,
        flag_set_max_heading_rate=False, max_heading_rate=math.nan)


def mode_completed(types: dict[str, Any], nav_state: int, success: bool) -> Any:
    return types["ModeCompleted"](timestamp=0, result=RESULT_SUCCESS if success else RESULT_FAILURE_OTHER,
                                  nav_state=nav_state)


def set_nav_state(types: dict[str, Any], nav_state: int, target_system: int, source_system: int,
                  source_component: int) -> Any:
    return types["VehicleCommand"](
        timestamp=0, param1=float(nav_state), param2=0.0, param3=0.0, param4=0.0, param5=0.0, param6=0.0,
        param7=0.0, command=CMD_SET_NAV_STATE, target_system=target_system, target_component=1,
        source_system=source_system, source_component=source_component, confirmation=0, from_external=True)


def executor_command(types: dict[str, Any], command: int, params: Sequence[float], target_system: int,
                     executor_id: int) -> Any:
    """A mode executor's command (for /fmu/in/vehicle_command_mode_executor): source_component 1000+id is how
    PX4 (Commander::handleCommandsFromModeExecutors) tells whether the executor is in charge; PX4 rewrites
    source_system itself, and answers to (its own system id, 1000+id)."""
    p = [float(x) for x in params] + [math.nan if i >= 4 else 0.0 for i in range(len(params), 7)]
    return types["VehicleCommand"](
        timestamp=0, param1=p[0], param2=p[1], param3=p[2], param4=p[3], param5=p[4], param6=p[5], param7=p[6],
        command=command, target_system=target_system, target_component=1, source_system=target_system,
        source_component=COMPONENT_MODE_EXECUTOR_START + executor_id, confirmation=0, from_external=True)


def overrides(types: dict[str, Any], mode_id: int, defer_failsafes: bool, defer_timeout_s: int,
              disable_auto_disarm: bool) -> Any:
    return types["ConfigOverrides"](
        timestamp=0, disable_auto_disarm=disable_auto_disarm, defer_failsafes=defer_failsafes,
        defer_failsafes_timeout_s=defer_timeout_s, disable_auto_set_home=False, source_type=SOURCE_TYPE_MODE,
        source_id=mode_id)
