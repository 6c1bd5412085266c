"""What an action's server and client share: the five parts' names, goal statuses, the answers a
server's callbacks give, goal ids (UUIDs) and stamps.

The names and statuses are ROS 2's (rcl_action, action_msgs/msg/GoalStatus), so an rmw_zenoh peer
finds the parts and reads the statuses as its own.
"""
from __future__ import annotations

import enum
import time
import uuid as _uuid
from typing import Any

from ..ros2.actions import Ros2ActionType, ros2_action_type

# The five parts of action <name>, as rcl_action names them.
SEND_GOAL, CANCEL_GOAL, GET_RESULT = "_action/send_goal", "_action/cancel_goal", "_action/get_result"
FEEDBACK, STATUS = "_action/feedback", "_action/status"
ACTION_INFIX = "/_action/"

DEFAULT_RESULT_TIMEOUT_S = 900.0      # rcl_action's default result_timeout: 15 minutes
DEFAULT_MAX_GOALS = 16                # goals accepted and not yet finished, at once
DEFAULT_MAX_RESULTS = 1024            # finished goals whose result is kept (oldest forgotten first)


class GoalStatus(enum.IntEnum):
    """action_msgs/msg/GoalStatus's constants."""
    STATUS_UNKNOWN = 0
    STATUS_ACCEPTED = 1
    STATUS_EXECUTING = 2
    STATUS_CANCELING = 3
    STATUS_SUCCEEDED = 4
    STATUS_CANCELED = 5
    STATUS_ABORTED = 6


ACTIVE = frozenset({GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING, GoalStatus.STATUS_CANCELING})
TERMINAL = frozenset({GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_CANCELED, GoalStatus.STATUS_ABORTED})


class GoalResponse(enum.Enum):
    """What a server's ``goal_callback`` answers (rclpy's names)."""
    REJECT = 1
    ACCEPT = 2


class CancelResponse(enum.Enum):
    """What a server's ``cancel_callback`` answers (rclpy's names)."""
    REJECT = 1
    ACCEPT = 2


class CancelReturn(enum.IntEnum):
    """action_msgs/srv/CancelGoal's return codes."""
    ERROR_NONE = 0
    ERROR_REJECTED = 1
    ERROR_UNKNOWN_GOAL_ID = 2
    ERROR_GOAL_TERMINATED = 3


def action_type(action: Ros2ActionType | str) -> Ros2ActionType:
    """An action type, or the known one of that name (``example_interfaces/action/Fibonacci``)."""
    return action if isinstance(action, Ros2ActionType) else ros2_action_type(action)


def new_goal_id() -> bytes:
    """A random goal id, as rclpy makes them (uuid4)."""
    return _uuid.uuid4().bytes


def goal_id_bytes(goal_id: Any) -> bytes:
    """The 16 bytes of a goal id given as a UUID message, bytes or a ``uuid.UUID``; ValueError otherwise."""
    raw = getattr(goal_id, "uuid", goal_id)
    if isinstance(raw, _uuid.UUID):
        raw = raw.bytes
    if isinstance(raw, (list, tuple)):
        raw = bytes(raw)
    if not isinstance(raw, (bytes, bytearray)) or len(raw) != 16:
        raise ValueError(f"a goal id is 16 bytes, got {goal_id!r}")
    return bytes(raw)


def goal_id_text(goal_id: bytes) -> str:
    """A goal id as ``ros2 action send_goal`` prints it (32 hex digits)."""
    return goal_id.hex()


def stamp_now() -> tuple[int, int]:
    """(sec, nanosec) of the wall clock, as builtin_interfaces/msg/Time holds it."""
    ns = time.time_ns()
    return ns // 1_000_000_000, ns % 1_000_000_000
