"""ROS 2 actions, rclpy-shaped, on either wire: a goal, its feedback, its cancel and its result.

An action ``<name>`` is five parts of the node, as rcl_action makes them: the services
``<name>/_action/send_goal``, ``cancel_goal``, ``get_result`` and the topics ``<name>/_action/feedback`` and
``<name>/_action/status`` (reliable, transient local, keep last 1). Their types are ROS 2's, derived
from the ``.action`` definition (``zenoh_robot.ros2.ros2_action_type``: ``Name_SendGoal``,
``Name_GetResult``, ``Name_FeedbackMessage``, action_msgs' ``CancelGoal`` and ``GoalStatusArray``, with
ROS 2's names and RIHS01 hashes). On a node of the ROS 2 wire the services and topics are rmw_zenoh's
(keys, ``SS``/``SC``/``MP``/``MS`` tokens), so a ROS 2 action client or server is the other end; on the
envelope wire they are the project's services (``@srv/<name>/_action/...``) and topics.

```python
Fibonacci = ros2_action_type("example_interfaces/action/Fibonacci")

def execute(goal_handle):
    seq = [0, 1]
    for i in range(1, goal_handle.request.order):
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
            return Fibonacci.Result(sequence=seq)
        seq.append(seq[i] + seq[i - 1])
        goal_handle.publish_feedback(Fibonacci.Feedback(sequence=seq))
    goal_handle.succeed()
    return Fibonacci.Result(sequence=seq)

node.create_action_server(Fibonacci, "fibonacci", execute)      # both nodes spinning (their executors
client = other.create_action_client(Fibonacci, "fibonacci")      # run the services and the feedback)
client.wait_for_server(5.0)
handle = client.send_goal_async(Fibonacci.Goal(order=10), feedback_callback=print).result()
print(handle.get_result_async().result().result.sequence)
```

Needs the ``ros2`` extra (rosbags) for the types, on both wires. Modules, one job each: types (names,
statuses, goal ids), goals (a server's bounded goal table: decisions, results, expiry), server
(ActionServer, ServerGoalHandle), client (ActionClient, ClientGoalHandle).
"""
from __future__ import annotations

from .client import ActionClient, ClientGoalHandle
from .server import ActionServer, ServerGoalHandle
from .types import (
    CANCEL_GOAL,
    DEFAULT_MAX_GOALS,
    DEFAULT_MAX_RESULTS,
    DEFAULT_RESULT_TIMEOUT_S,
    FEEDBACK,
    GET_RESULT,
    SEND_GOAL,
    STATUS,
    CancelResponse,
    CancelReturn,
    GoalResponse,
    GoalStatus,
    goal_id_text,
)

__all__ = [
    "CANCEL_GOAL",
    "DEFAULT_MAX_GOALS",
    "DEFAULT_MAX_RESULTS",
    "DEFAULT_RESULT_TIMEOUT_S",
    "FEEDBACK",
    "GET_RESULT",
    "SEND_GOAL",
    "STATUS",
    "ActionClient",
    "ActionServer",
    "CancelResponse",
    "CancelReturn",
    "ClientGoalHandle",
    "GoalResponse",
    "GoalStatus",
    "ServerGoalHandle",
    "goal_id_text",
]
