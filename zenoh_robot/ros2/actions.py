"""ROS 2 action types at run time: an ``.action`` definition (Goal ``---`` Result ``---`` Feedback) ->
the types ROS 2 derives from it, named and hashed as rosidl does, so rmw_zenoh peers match them.

For ``pkg/action/Name`` rosidl generates, and rmw_zenoh carries:

- ``pkg/action/Name_Goal``, ``_Result``, ``_Feedback``: the three sections as messages;
- ``pkg/action/Name_SendGoal``: a service, request ``goal_id`` (unique_identifier_msgs/msg/UUID) + ``goal``,
  response ``accepted`` (bool) + ``stamp`` (builtin_interfaces/msg/Time);
- ``pkg/action/Name_GetResult``: a service, request ``goal_id``, response ``status`` (int8) + ``result``;
- ``pkg/action/Name_FeedbackMessage``: a message, ``goal_id`` + ``feedback``;
- and, shared by every action, ``action_msgs/srv/CancelGoal`` and ``action_msgs/msg/GoalStatusArray``.

The two services are hashed as any service here (``services.py``: request, response and the
``_Event`` type), which gives ROS 2's published hashes (turtlesim_msgs/action/RotateAbsolute_SendGoal
``RIHS01_3d5d3cfc...``, tests/library/test_ros2_actions.py). Needs the ``ros2`` extra (rosbags).

Threading: types are made once under the typestore's lock and are immutable after.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from .services import Ros2ServiceType, Ros2TypeError, ros2_service_type, service_from_definitions
from .types import ask_provider, parse_definition, register_definitions, rihs01, ros2_type

UUID = "unique_identifier_msgs/msg/UUID"
TIME = "builtin_interfaces/msg/Time"
GOAL_INFO = "action_msgs/msg/GoalInfo"
GOAL_STATUS = "action_msgs/msg/GoalStatus"
GOAL_STATUS_ARRAY = "action_msgs/msg/GoalStatusArray"
CANCEL_GOAL = "action_msgs/srv/CancelGoal"

# A few standard actions, so `ros2_action_type("example_interfaces/action/Fibonacci")` needs no file;
# any other action is given its .action text.
KNOWN_ACTIONS: dict[str, str] = {
    "example_interfaces/action/Fibonacci": "int32 order\n---\nint32[] sequence\n---\nint32[] sequence\n",
}


@dataclass(frozen=True)
class Ros2ActionType:
    """One ROS 2 action type: its name and every type its five parts use. The message classes are
    generated at run time (typed ``Any``: their fields are unknown to a type checker)."""
    name: str                            # example_interfaces/action/Fibonacci
    goal: Any                            # ..._Goal
    result: Any                          # ..._Result
    feedback: Any                        # ..._Feedback
    feedback_message: Any                # ..._FeedbackMessage (goal_id, feedback)
    send_goal: Ros2ServiceType           # ..._SendGoal
    get_result: Ros2ServiceType          # ..._GetResult
    cancel_goal: Ros2ServiceType         # action_msgs/srv/CancelGoal
    goal_status_array: Any               # action_msgs/msg/GoalStatusArray
    goal_status: Any                     # action_msgs/msg/GoalStatus
    goal_info: Any                       # action_msgs/msg/GoalInfo
    uuid: Any                            # unique_identifier_msgs/msg/UUID
    time: Any                            # builtin_interfaces/msg/Time

    # rclpy's spelling (``Fibonacci.Goal(order=5)``), so code written for rclpy reads the same.
    @property
    def Goal(self) -> Any:  # noqa: N802
        return self.goal

    @property
    def Result(self) -> Any:  # noqa: N802
        return self.result

    @property
    def Feedback(self) -> Any:  # noqa: N802
        return self.feedback

    @property
    def feedback_hash(self) -> str:
        return str(getattr(self.feedback_message, "_type_hash", ""))


_lock = threading.Lock()
_types: dict[str, Ros2ActionType] = {}
_provided: dict[str, str] = {}      # .action texts installed packages provide (provide_action)


def provide_action(name: str, definition: str) -> None:
    """An installed package's ``.action`` text for ``name``, from its ``zenoh_robot.ros2_types`` entry
    point (named after the ROS package): ``ros2_action_type(name)`` then needs no text, so the tools
    (``zenoh-robot action send_goal``) call the drone's actions without importing the drone wing."""
    with _lock:
        _provided[name] = definition


def _split(name: str, text: str) -> tuple[str, str, str]:
    lines = text.splitlines()
    cuts = [i for i, line in enumerate(lines) if line.strip() == "---"]
    if len(cuts) != 2:
        raise Ros2TypeError(f"{name}: an .action definition has two '---' lines (goal, result, feedback), "
                            f"got {len(cuts)}")
    a, b = cuts
    return "\n".join(lines[:a]), "\n".join(lines[a + 1:b]), "\n".join(lines[b + 1:])


def ros2_action_type(name: str, definition: str | None = None) -> Ros2ActionType:
    """The action type ``name`` (``pkg/action/Name``) from its ``.action`` text, or from
    :data:`KNOWN_ACTIONS`. Made once per name; :class:`Ros2TypeError` for a bad name or definition."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] != "action" or not all(parts):
        raise Ros2TypeError(f"a ROS 2 action type is PKG/action/NAME, got {name!r}")
    with _lock:
        known = _types.get(name)
        if known is not None:
            return known
        text = definition if definition is not None else KNOWN_ACTIONS.get(name, _provided.get(name))
    if text is None:
        ask_provider(parts[0])        # outside the lock: the provider calls provide_action
        text = _provided.get(name)
    with _lock:
        known = _types.get(name)
        if known is not None:
            return known
        if text is None:
            raise Ros2TypeError(f"no definition for action type {name}: give its .action text "
                                f"(known here: {', '.join(sorted({*KNOWN_ACTIONS, *_provided}))})")
        try:
            action = _make(name, *_split(name, text))
        except Ros2TypeError:
            raise
        except Exception as exc:
            raise Ros2TypeError(f"{name}: {exc}") from None
        _types[name] = action
        return action


def _make(name: str, goal_text: str, result_text: str, feedback_text: str) -> Ros2ActionType:
    from rosbags.interfaces import Nodetype

    def named(typ: str) -> tuple[Any, str]:
        return (Nodetype.NAME, typ)

    sections: dict[str, Any] = {}
    for suffix, text in (("_Goal", goal_text), ("_Result", result_text), ("_Feedback", feedback_text)):
        sections.update(parse_definition(text, name + suffix))
    sections[name + "_FeedbackMessage"] = ([], [("goal_id", named(UUID)), ("feedback", named(name + "_Feedback"))])
    register_definitions(sections)
    send_goal = service_from_definitions(name + "_SendGoal", {
        name + "_SendGoal_Request": ([], [("goal_id", named(UUID)), ("goal", named(name + "_Goal"))]),
        name + "_SendGoal_Response": ([], [("accepted", (Nodetype.BASE, ("bool", 0))), ("stamp", named(TIME))]),
    })
    get_result = service_from_definitions(name + "_GetResult", {
        name + "_GetResult_Request": ([], [("goal_id", named(UUID))]),
        name + "_GetResult_Response": ([], [("status", (Nodetype.BASE, ("int8", 0))),
                                            ("result", named(name + "_Result"))]),
    })
    rihs01(name + "_FeedbackMessage")      # fails here, naming the action, if a nested type is unknown
    return Ros2ActionType(
        name, ros2_type(name + "_Goal"), ros2_type(name + "_Result"), ros2_type(name + "_Feedback"),
        ros2_type(name + "_FeedbackMessage"), send_goal, get_result, ros2_service_type(CANCEL_GOAL),
        ros2_type(GOAL_STATUS_ARRAY), ros2_type(GOAL_STATUS), ros2_type(GOAL_INFO), ros2_type(UUID),
        ros2_type(TIME))


def action_definition(action: Ros2ActionType) -> str:
    """The ``.action`` text of a known action (each section as :func:`msg_definition` writes it)."""
    from .types import msg_definition

    return "---\n".join(msg_definition(t) for t in (action.goal._type_name, action.result._type_name,
                                                   action.feedback._type_name))
