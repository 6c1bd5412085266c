"""An action client, rclpy-shaped: three service clients and two subscriptions of the node.

``send_goal_async(goal, feedback_callback=...)`` -> a Future of a :class:`ClientGoalHandle` (accepted or
not, the server's stamp); the handle's ``status`` follows the server's status topic, and
``get_result_async()`` / ``cancel_goal_async()`` give Futures of the GetResult and CancelGoal responses.
Futures complete on Zenoh's threads (keep done-callbacks short); feedback callbacks run on the
node's executor, as rclpy's do (so the node must spin to get feedback).

Lossy links: a goal keeps its id across resends (the server answers a known id with its first
decision and never runs it twice); ``retry`` is passed to the envelope's service clients
(services.RetryPolicy / AdaptiveRetry, which resend the same bytes). A get_result whose reply does
not come within ``result_poll_s`` is asked again while a server is there: a goal may run for long,
and a lost reply must not lose the result; a server gone (on a multicast session, where
nothing is discovered: no peer reachable) is a ServiceUnavailable.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

from ..ros2.actions import Ros2ActionType
from ..services.errors import ServiceTimeout, ServiceUnavailable
from ..services.retry import _DEFAULT, RetryPolicy
from ..services.ros2 import complete_future
from ..services.scheduler import _scheduler
from .server import FEEDBACK_QOS, STATUS_QOS
from .types import (
    CANCEL_GOAL,
    FEEDBACK,
    GET_RESULT,
    SEND_GOAL,
    STATUS,
    TERMINAL,
    GoalStatus,
    action_type,
    goal_id_bytes,
    goal_id_text,
    new_goal_id,
)

if TYPE_CHECKING:
    from ..node import Node

log = logging.getLogger("zenoh_robot.actions")

FeedbackCallback = Callable[[Any], None]
MAX_TRACKED_GOALS = 1024      # goals whose feedback and status this client follows (oldest finished dropped)
RESULT_RETRY = RetryPolicy(interval_s=0.05, multiplier=1.5, max_interval_s=1.0)
REASK_S = 0.5                 # get_result asked again at most this often (a reply that ends at once)


class ClientGoalHandle:
    """A goal as its client sees it (rclpy's ClientGoalHandle)."""

    def __init__(self, client: ActionClient, goal_id: bytes, accepted: bool, stamp: Any) -> None:
        self._client = client
        self._id = goal_id
        self.goal_id = client.action.uuid(uuid=goal_id)
        self.accepted = bool(accepted)
        self.stamp = stamp                        # builtin_interfaces/msg/Time: when the server decided
        self._status = GoalStatus.STATUS_ACCEPTED if accepted else GoalStatus.STATUS_UNKNOWN

    @property
    def status(self) -> int:
        return int(self._status)

    @property
    def goal_id_text(self) -> str:
        return goal_id_text(self._id)

    def get_result_async(self) -> Future[Any]:
        """A Future of the GetResult response (``status``, ``result``); STATUS_UNKNOWN if the server
        does not know the goal (never accepted, or its result expired)."""
        if not self.accepted:
            raise RuntimeError(f"goal {self.goal_id_text} was rejected: it has no result")
        return self._client._get_result_async(self)

    def cancel_goal_async(self) -> Future[Any]:
        """A Future of the CancelGoal response (``return_code``, ``goals_canceling``)."""
        return self._client._cancel_goal_async(self._id)

    def __repr__(self) -> str:
        return (f"ClientGoalHandle({self.goal_id_text}, accepted={self.accepted}, "
                f"status={GoalStatus(self._status).name})")


class _Tracked:
    __slots__ = ("feedback", "handle", "status")

    def __init__(self, feedback: FeedbackCallback | None) -> None:
        self.feedback = feedback
        self.handle: ClientGoalHandle | None = None
        self.status: GoalStatus | None = None     # seen on the status topic before the handle existed


class ActionClient:
    """``ActionClient(node, Fibonacci, "fibonacci")``; ``wait_for_server()``, ``send_goal_async(goal, ...)``."""

    def __init__(self, node: Node, action: Ros2ActionType | str, name: str, *, goal_timeout: float = 10.0,
                 result_poll_s: float = 30.0, retry: Any = _DEFAULT) -> None:
        if not goal_timeout > 0 or not result_poll_s > 0:
            raise ValueError(f"goal_timeout and result_poll_s must be > 0, got {goal_timeout!r}, {result_poll_s!r}")
        self.action = a = action_type(action)
        self.node = node
        self.name = name
        self.action_name = node.resolve_topic_name(name)
        self.goal_timeout = goal_timeout
        self.result_poll_s = result_poll_s
        self._lock = threading.Lock()
        self._goals: OrderedDict[bytes, _Tracked] = OrderedDict()
        self._destroyed = False
        # Generated classes (typed Any: their fields are unknown to a type checker).
        self._goal_request_t: Any = a.send_goal.request
        self._result_request_t: Any = a.get_result.request
        self._cancel_request_t: Any = a.cancel_goal.request
        self._send = node.create_client(f"{name}/{SEND_GOAL}", a.send_goal.request, a.send_goal.response, retry=retry)
        self._cancel = node.create_client(f"{name}/{CANCEL_GOAL}", a.cancel_goal.request, a.cancel_goal.response,
                                          retry=retry)
        # A get_result is held open by the server until its goal ends (a goto: minutes), so re-sending it every
        # 10-50 ms as a command is would cost the radio ~100 copies a second for nothing: the first copies come
        # quickly (one must cross the loss), then one a second at most.
        self._result = node.create_client(f"{name}/{GET_RESULT}", a.get_result.request, a.get_result.response,
                                          retry=RESULT_RETRY if retry is _DEFAULT else retry)
        self._feedback_sub = node.create_subscription(a.feedback_message, f"{name}/{FEEDBACK}", self._on_feedback,
                                                      FEEDBACK_QOS)
        self._status_sub = node.create_subscription(a.goal_status_array, f"{name}/{STATUS}", self._on_status,
                                                    STATUS_QOS)
        node.add_on_close(self.destroy)

    # -- discovery ---------------------------------------------------------------------------------
    def server_is_ready(self) -> bool:
        """Whether a server of each of the three services is known (rclpy's check)."""
        return all(c.service_is_ready() for c in (self._send, self._cancel, self._result))

    def wait_for_server(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.server_is_ready():
            if self._destroyed or self.node.closed or (deadline is not None and time.monotonic() >= deadline):
                return False
            time.sleep(0.02)
        return True

    # -- goals ----------------------------------------------------------------------------------------
    def send_goal_async(self, goal: Any, feedback_callback: FeedbackCallback | None = None,
                        goal_uuid: Any = None) -> Future[ClientGoalHandle]:
        """Send ``goal`` (the action's Goal message); the Future gives the handle once the server decided.
        ``goal_uuid``: the goal id to use (16 bytes, a UUID message or ``uuid.UUID``), e.g. to resend a goal."""
        if not isinstance(goal, self.action.goal):
            raise TypeError(f"action {self.action_name} takes {self.action.name}_Goal, got {type(goal).__name__}")
        goal_id = new_goal_id() if goal_uuid is None else goal_id_bytes(goal_uuid)
        with self._lock:
            self._track(goal_id, feedback_callback)
        request = self._goal_request_t(goal_id=self.action.uuid(uuid=goal_id), goal=goal)
        out: Future[ClientGoalHandle] = Future()

        def decided(call: Future[Any]) -> None:
            try:
                response = call.result()
            except BaseException as exc:  # noqa: BLE001  (the caller hears every failure)
                self._forget(goal_id)
                complete_future(out, exc=exc)
                return
            handle = ClientGoalHandle(self, goal_id, response.accepted, response.stamp)
            with self._lock:
                tracked = self._goals.get(goal_id)
                if tracked is not None and response.accepted:
                    tracked.handle = handle
                    if tracked.status is not None:
                        handle._status = tracked.status
            if not response.accepted:
                self._forget(goal_id)
            complete_future(out, result=handle)
        self._send.call_async(request, self.goal_timeout).add_done_callback(decided)
        return out

    def send_goal(self, goal: Any, feedback_callback: FeedbackCallback | None = None,
                  timeout: float | None = None) -> Any:
        """Send ``goal`` and wait for its GetResult response (None if the goal was rejected), as rclpy's."""
        handle = self.send_goal_async(goal, feedback_callback).result(timeout)
        if not handle.accepted:
            return None
        return handle.get_result_async().result(timeout)

    def _track(self, goal_id: bytes, feedback: FeedbackCallback | None) -> None:
        self._goals[goal_id] = _Tracked(feedback)
        self._goals.move_to_end(goal_id)
        while len(self._goals) > MAX_TRACKED_GOALS:
            old = next((k for k, t in self._goals.items() if t.handle is None or t.handle._status in TERMINAL),
                       next(iter(self._goals)))
            del self._goals[old]

    def _forget(self, goal_id: bytes) -> None:
        with self._lock:
            self._goals.pop(goal_id, None)

    def _get_result_async(self, handle: ClientGoalHandle) -> Future[Any]:
        out: Future[Any] = Future()
        request = self._result_request_t(goal_id=self.action.uuid(uuid=handle._id))

        def ask() -> None:
            if self._destroyed or out.done():
                return
            started = time.monotonic()
            try:
                self._result.call_async(request, self.result_poll_s).add_done_callback(
                    lambda call: answered(call, started))
            except BaseException as exc:  # noqa: BLE001
                complete_future(out, exc=exc)

        def answered(call: Future[Any], started: float) -> None:
            try:
                response = call.result()
            except ServiceTimeout:
                # Not an answer: the goal still runs, or the reply was lost; asked again, off Zenoh's thread
                # and never faster than REASK_S. A server that is gone is an answer: the caller hears it.
                if not self._server_reachable():
                    complete_future(out, exc=ServiceUnavailable(f"action {self.action_name}: no server for "
                                                          f"goal {handle.goal_id_text}'s result"))
                    return
                _scheduler.at(max(time.monotonic(), started + REASK_S), ask)
                return
            except BaseException as exc:  # noqa: BLE001
                complete_future(out, exc=exc)
                return
            if response.status in (s.value for s in GoalStatus):
                handle._status = GoalStatus(response.status)
            complete_future(out, result=response)
        ask()
        return out

    def _server_reachable(self) -> bool:
        """Whether a get_result that got no reply may be asked again. On a multicast session nothing is
        discovered and ``service_is_ready()`` says only that a get_result was answered once, which a
        goal running longer than ``result_poll_s`` never was: there a server is reachable while the
        link to a peer is up (its lease ends ~10 s after the peer is gone)."""
        if getattr(self._result, "discovers_servers", True):
            return bool(self._result.service_is_ready())
        return self.node.link_up()

    def _cancel_goal_async(self, goal_id: bytes) -> Future[Any]:
        a = self.action
        request = self._cancel_request_t(goal_info=a.goal_info(goal_id=a.uuid(uuid=goal_id), stamp=a.time()))
        future: Future[Any] = self._cancel.call_async(request, self.goal_timeout)
        return future

    # -- topics (node's executor) ------------------------------------------------------------------------
    def _on_feedback(self, msg: Any) -> None:
        with self._lock:
            tracked = self._goals.get(bytes(msg.goal_id.uuid))
        if tracked is not None and tracked.feedback is not None:
            tracked.feedback(msg)

    def _on_status(self, msg: Any) -> None:
        known = {s.value for s in GoalStatus}
        with self._lock:
            for entry in msg.status_list:
                tracked = self._goals.get(bytes(entry.goal_info.goal_id.uuid))
                if tracked is None or entry.status not in known:
                    continue
                status = GoalStatus(entry.status)
                tracked.status = status
                if tracked.handle is not None:
                    tracked.handle._status = status

    # -- lifetime ------------------------------------------------------------------------------------------
    def destroy(self) -> None:
        with self._lock:
            if self._destroyed:
                return
            self._destroyed = True
        for client in (self._send, self._cancel, self._result):
            self.node.destroy_client(client)
        for sub in (self._feedback_sub, self._status_sub):
            self.node.destroy_subscription(sub)
