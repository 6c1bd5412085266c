"""An action server, rclpy-shaped: three services and two publishers of the node, under ``<name>/_action/``.

- ``send_goal``: a new goal id goes to ``goal_callback`` (default: accept) unless ``max_goals`` goals are
  active; an accepted goal runs ``execute_callback(goal_handle) -> Result`` on a thread of its own, so
  a long goal never holds the node's executor. A goal id seen before gets the first answer again
  (accepted or not, same stamp) and never starts a second execution: a lossy link's resend is harmless.
- ``cancel_goal``: ROS 2's rules (a zero id and stamp cancel every goal; a stamp, those accepted at
  or before it); ``cancel_callback`` decides (default, as rclpy: reject); the reply names the goals now
  canceling, else why none (rejected, unknown goal id, goal terminated).
- ``get_result``: answered when the goal ends (the reply is a Future the service completes); an
  unknown or forgotten goal id is answered at once with STATUS_UNKNOWN.
- ``feedback``: ``goal_handle.publish_feedback(feedback)``; ``status``: every kept goal's status on
  each change, reliable, transient local, keep last 1 (so a late client gets the current one).

Fields from peers are checked by the types' decoders before a handler runs; a zero goal id, a stamp
with nanosec >= 1e9 are refused here.

Threads: the handlers run on the node's executor; executions each on their own thread; the goal
table under one lock; callbacks (goal, cancel) are called outside it.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

from ..qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from ..ros2.actions import Ros2ActionType
from .goals import Goal, GoalTable
from .types import (
    ACTIVE,
    CANCEL_GOAL,
    DEFAULT_MAX_GOALS,
    DEFAULT_MAX_RESULTS,
    DEFAULT_RESULT_TIMEOUT_S,
    FEEDBACK,
    GET_RESULT,
    SEND_GOAL,
    STATUS,
    TERMINAL,
    CancelResponse,
    CancelReturn,
    GoalResponse,
    GoalStatus,
    action_type,
    goal_id_text,
    stamp_now,
)

if TYPE_CHECKING:
    from ..node import Node

log = logging.getLogger("zenoh_robot.actions")

STATUS_QOS = QoSProfile(ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL, HistoryPolicy.KEEP_LAST, 1)
FEEDBACK_QOS = QoSProfile(depth=10)
MAX_RESULT_WAITERS = 256     # get_result requests held open at once (each holds a query until its goal ends)
_ZERO_ID = bytes(16)

# The moves rcl_action allows (its goal state machine).
_MOVES: dict[GoalStatus, frozenset[GoalStatus]] = {
    GoalStatus.STATUS_ACCEPTED: frozenset({GoalStatus.STATUS_EXECUTING, GoalStatus.STATUS_CANCELING}),
    GoalStatus.STATUS_EXECUTING: frozenset({GoalStatus.STATUS_CANCELING, GoalStatus.STATUS_SUCCEEDED,
                                            GoalStatus.STATUS_ABORTED}),
    GoalStatus.STATUS_CANCELING: frozenset({GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED,
                                            GoalStatus.STATUS_CANCELED}),
}


class ServerGoalHandle:
    """One accepted goal as ``execute_callback`` sees it (rclpy's ServerGoalHandle)."""

    def __init__(self, server: ActionServer, goal_id: bytes, request: Any, stamp: tuple[int, int]) -> None:
        self._server = server
        self._id = goal_id
        self.goal_id = server.action.uuid(uuid=goal_id)     # unique_identifier_msgs/msg/UUID
        self.request = request                              # the Goal message
        self.stamp = stamp
        self._status = GoalStatus.STATUS_ACCEPTED
        self._cancel_requested = False

    @property
    def status(self) -> int:
        return int(self._status)

    @property
    def is_active(self) -> bool:
        return self._status in ACTIVE

    @property
    def is_cancel_requested(self) -> bool:
        return self._cancel_requested

    def publish_feedback(self, feedback: Any) -> None:
        """Send ``feedback`` (the action's Feedback message) to the clients; ignored once the goal ended."""
        if not isinstance(feedback, self._server.action.feedback):
            raise TypeError(f"publish_feedback takes {self._server.action.name}_Feedback, "
                            f"got {type(feedback).__name__}")
        if self.is_active:
            self._server._publish_feedback(self._id, feedback)

    def succeed(self) -> None:
        self._server._move(self, GoalStatus.STATUS_SUCCEEDED)

    def abort(self) -> None:
        self._server._move(self, GoalStatus.STATUS_ABORTED)

    def canceled(self) -> None:
        self._server._move(self, GoalStatus.STATUS_CANCELED)

    def __repr__(self) -> str:
        return f"ServerGoalHandle({goal_id_text(self._id)}, {self._status.name})"


ExecuteCallback = Callable[[ServerGoalHandle], Any]
GoalCallback = Callable[[Any], GoalResponse]
CancelCallback = Callable[[ServerGoalHandle], CancelResponse]


def _accept(_goal: Any) -> GoalResponse:
    return GoalResponse.ACCEPT


def _reject_cancel(_handle: ServerGoalHandle) -> CancelResponse:
    return CancelResponse.REJECT       # rclpy's default: a server cancels only when it says it can


class ActionServer:
    """``ActionServer(node, Fibonacci, "fibonacci", execute_callback, goal_callback=..., cancel_callback=...)``."""

    def __init__(self, node: Node, action: Ros2ActionType | str, name: str, execute_callback: ExecuteCallback, *,
                 goal_callback: GoalCallback | None = None, cancel_callback: CancelCallback | None = None,
                 max_goals: int = DEFAULT_MAX_GOALS, max_results: int = DEFAULT_MAX_RESULTS,
                 result_timeout: float = DEFAULT_RESULT_TIMEOUT_S) -> None:
        for what, fn in (("execute_callback", execute_callback), ("goal_callback", goal_callback),
                         ("cancel_callback", cancel_callback)):
            if fn is not None and not callable(fn):
                raise TypeError(f"action server {name!r}: {what} must be callable")
        self.action = action_type(action)
        self.node = node
        self.name = name
        self.action_name = node.resolve_topic_name(name)
        self._execute = execute_callback
        self._goal_cb = goal_callback or _accept
        self._cancel_cb = cancel_callback or _reject_cancel
        self._goals = GoalTable(max_goals, max_results, result_timeout)
        self._lock = threading.RLock()
        self._decide = threading.Lock()     # one send_goal decision at a time: two copies of a goal, one answer
        self._waiters = 0
        self._destroyed = False
        self.executions = 0      # execute_callback runs started
        self.duplicates = 0      # send_goal requests answered from an earlier decision
        self.rejected = 0
        a = self.action
        # Generated classes (typed Any: their fields are unknown to a type checker).
        self._goal_response_t: Any = a.send_goal.response
        self._result_response_t: Any = a.get_result.response
        self._cancel_response_t: Any = a.cancel_goal.response
        self._feedback_pub = node.create_publisher(a.feedback_message, f"{name}/{FEEDBACK}", FEEDBACK_QOS)
        self._status_pub = node.create_publisher(a.goal_status_array, f"{name}/{STATUS}", STATUS_QOS)
        self._services = [
            node.create_service(f"{name}/{SEND_GOAL}", a.send_goal.request, a.send_goal.response, self._on_send_goal),
            node.create_service(f"{name}/{CANCEL_GOAL}", a.cancel_goal.request, a.cancel_goal.response,
                                self._on_cancel),
            node.create_service(f"{name}/{GET_RESULT}", a.get_result.request, a.get_result.response,
                                self._on_get_result),
        ]
        node.add_on_close(self.destroy)

    # -- send_goal (node's executor) ----------------------------------------------------------
    def _on_send_goal(self, request: Any) -> Any:
        goal_id = bytes(request.goal_id.uuid)
        with self._decide:
            with self._lock:
                self._expire()
                earlier = self._goals.decision(goal_id)
                if earlier is not None:
                    self.duplicates += 1
                    return self._goal_response(*earlier)
                full = self._goals.full()
            stamp = stamp_now()
            accepted = False
            if goal_id == _ZERO_ID:
                log.warning("action %s: refused a goal with the zero goal id", self.action_name)
                return self._goal_response(False, stamp)   # not remembered: it names no goal
            if full:
                log.warning("action %s: rejected goal %s: %d goals active (max_goals)", self.action_name,
                            goal_id_text(goal_id), self._goals.max_goals)
            elif not self._destroyed:
                accepted = self._ask_goal_callback(request.goal)
            handle = ServerGoalHandle(self, goal_id, request.goal, stamp)
            with self._lock:
                self._goals.decide(goal_id, accepted, stamp)
                if accepted:
                    self._goals.add(Goal(goal_id, stamp, handle))
                else:
                    self.rejected += 1
        if accepted:
            self._publish_status()
            self._start(handle)
        return self._goal_response(accepted, stamp)

    def _ask_goal_callback(self, goal: Any) -> bool:
        try:
            answer = self._goal_cb(goal)
        except Exception as exc:
            log.warning("action %s: goal_callback raised %s: %s (goal rejected)", self.action_name,
                        type(exc).__name__, exc)
            return False
        return answer is GoalResponse.ACCEPT

    def _goal_response(self, accepted: bool, stamp: tuple[int, int]) -> Any:
        return self._goal_response_t(accepted=accepted, stamp=self.action.time(sec=stamp[0], nanosec=stamp[1]))

    # -- execution (a thread per goal) -----------------------------------------------------------
    def _start(self, handle: ServerGoalHandle) -> None:
        thread = threading.Thread(target=self._run, args=(handle,), daemon=True,
                                  name=f"zr-action-{goal_id_text(handle._id)[:8]}")
        with self._lock:
            self.executions += 1
        thread.start()

    def _run(self, handle: ServerGoalHandle) -> None:
        self._moved(handle, GoalStatus.STATUS_EXECUTING)     # unless a cancel came first: it stays CANCELING
        result: Any = None
        try:
            result = self._execute(handle)
        except Exception as exc:
            log.warning("action %s: execute_callback raised %s: %s (goal %s aborted)", self.action_name,
                        type(exc).__name__, exc, goal_id_text(handle._id))
        if not isinstance(result, self.action.result):
            if result is not None:
                log.warning("action %s: execute_callback returned %s, not %s_Result (an empty result is sent)",
                            self.action_name, type(result).__name__, self.action.name)
            result = self.action.result()
        if handle.is_active:
            # rclpy's rule: a goal whose state the callback did not set is aborted.
            log.warning("action %s: goal %s ended without succeed/abort/canceled: aborted", self.action_name,
                        goal_id_text(handle._id))
            self._moved(handle, GoalStatus.STATUS_ABORTED)
        self._finish(handle, result)

    def _move(self, handle: ServerGoalHandle, to: GoalStatus) -> None:
        """The execute callback's move: one ROS 2 does not allow is its mistake (RuntimeError)."""
        with self._lock:
            was = handle._status
        if not self._moved(handle, to):
            raise RuntimeError(f"goal {goal_id_text(handle._id)}: cannot go from {was.name} to {to.name}")

    def _moved(self, handle: ServerGoalHandle, to: GoalStatus, before: Callable[[], None] | None = None) -> bool:
        """Move ``handle`` to ``to`` if ROS 2 allows it from where it is now (checked and done under the lock,
        as a cancel and the execution race), publishing the status; whether it moved."""
        with self._lock:
            if to not in _MOVES.get(handle._status, frozenset()):
                return False
            if before is not None:
                before()
            handle._status = to
        self._publish_status()
        return True

    def _finish(self, handle: ServerGoalHandle, result: Any) -> None:
        with self._lock:
            goal = self._goals.get(handle._id)
            if goal is not None:
                self._goals.finished(goal)
        if goal is not None and not goal.result.done():
            goal.result.set_result(self._result_response_t(status=handle.status, result=result))
        self._publish_status()

    # -- cancel_goal (node's executor) ----------------------------------------------------------
    def _on_cancel(self, request: Any) -> Any:
        info = request.goal_info
        goal_id, stamp = bytes(info.goal_id.uuid), (int(info.stamp.sec), int(info.stamp.nanosec))
        response = self._cancel_response_t
        if stamp[1] >= 1_000_000_000:
            return response(return_code=int(CancelReturn.ERROR_REJECTED))
        with self._lock:
            self._expire()
            goals = list(self._goals)
            one = self._goals.get(goal_id) if goal_id != _ZERO_ID else None
        if goal_id != _ZERO_ID and one is None:
            return response(return_code=int(CancelReturn.ERROR_UNKNOWN_GOAL_ID))
        if goal_id == _ZERO_ID:
            chosen = [g for g in goals if stamp == (0, 0) or g.stamp <= stamp]
        else:
            chosen = [g for g in goals if g is one or (stamp != (0, 0) and g.stamp <= stamp)]
        canceling = [g for g in chosen if self._cancel_one(g.handle)]
        if canceling:
            infos = [self.action.goal_info(goal_id=self.action.uuid(uuid=g.goal_id),
                                           stamp=self.action.time(sec=g.stamp[0], nanosec=g.stamp[1]))
                     for g in canceling]
            return response(return_code=int(CancelReturn.ERROR_NONE), goals_canceling=infos)
        if one is not None and one.status in TERMINAL:
            return response(return_code=int(CancelReturn.ERROR_GOAL_TERMINATED))
        return response(return_code=int(CancelReturn.ERROR_REJECTED))

    def _cancel_one(self, handle: ServerGoalHandle) -> bool:
        if handle._status is GoalStatus.STATUS_CANCELING:
            return True      # asked twice (a resent cancel): still canceling, same answer
        if handle._status in TERMINAL:
            return False
        try:
            answer = self._cancel_cb(handle)
        except Exception as exc:
            log.warning("action %s: cancel_callback raised %s: %s (cancel rejected)", self.action_name,
                        type(exc).__name__, exc)
            return False
        if answer is not CancelResponse.ACCEPT:
            return False

        def requested() -> None:
            handle._cancel_requested = True
        # The goal may have ended (or been canceled by another request) while the callback decided.
        return self._moved(handle, GoalStatus.STATUS_CANCELING, requested) or \
            handle.status == GoalStatus.STATUS_CANCELING

    # -- get_result (node's executor) ----------------------------------------------------------
    def _on_get_result(self, request: Any) -> Any:
        goal_id = bytes(request.goal_id.uuid)
        with self._lock:
            self._expire()
            goal = self._goals.get(goal_id)
            if goal is None:
                return self._result_response_t(status=int(GoalStatus.STATUS_UNKNOWN))
            if goal.result.done():
                return goal.result.result()
            if self._waiters >= MAX_RESULT_WAITERS:
                raise RuntimeError(f"{MAX_RESULT_WAITERS} get_result requests already waiting")
            self._waiters += 1
        later: Future[Any] = Future()

        def settle(done: Future[Any]) -> None:
            with self._lock:
                self._waiters -= 1
            later.set_result(done.result())
        goal.result.add_done_callback(settle)
        return later

    # -- topics ------------------------------------------------------------------------------------
    def _publish_feedback(self, goal_id: bytes, feedback: Any) -> None:
        if self._destroyed:
            return
        try:
            self._feedback_pub.publish(self.action.feedback_message(goal_id=self.action.uuid(uuid=goal_id),
                                                                    feedback=feedback))
        except Exception as exc:      # the node closing under a running goal
            log.debug("action %s: feedback not sent: %s", self.action_name, exc)

    def _publish_status(self) -> None:
        a = self.action
        with self._lock:
            if self._destroyed:
                return
            statuses = [a.goal_status(goal_info=a.goal_info(goal_id=a.uuid(uuid=g.goal_id),
                                                            stamp=a.time(sec=g.stamp[0], nanosec=g.stamp[1])),
                                      status=g.handle.status) for g in self._goals]
            try:
                self._status_pub.publish(a.goal_status_array(status_list=statuses))
            except Exception as exc:
                log.debug("action %s: status not sent: %s", self.action_name, exc)

    def _expire(self) -> None:
        if self._goals.expire():
            threading.Thread(target=self._publish_status, daemon=True).start()

    # -- introspection, lifetime --------------------------------------------------------------------
    def get_feedback_subscription_count(self) -> int:
        """Clients (their feedback subscriptions) matched now."""
        return self._feedback_pub.get_subscription_count()

    def goal_handles(self) -> list[ServerGoalHandle]:
        """Every goal kept (active, and finished until its result expires)."""
        with self._lock:
            return [g.handle for g in self._goals]

    def destroy(self) -> None:
        """Stop serving; running goals are asked to cancel (``is_cancel_requested``) and their results dropped."""
        with self._lock:
            if self._destroyed:
                return
            self._destroyed = True
            for g in self._goals:
                g.handle._cancel_requested = True
        for srv in self._services:
            self.node.destroy_service(srv)
        for pub in (self._feedback_pub, self._status_pub):
            self.node.destroy_publisher(pub)
