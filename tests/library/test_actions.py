"""Actions on the envelope wire, between two in-process nodes: a goal with feedback and result, the
goal, cancel and result refusals a client hears, the bounds (concurrent goals, kept results, result
expiry), and a resent goal id that never runs twice. Every wait is for an event, none for a time.
"""
from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from typing import Any

import pytest
from conftest import spinning_nodes, wait_for

from zenoh_robot import Node
from zenoh_robot.actions import (
    ActionServer,
    CancelResponse,
    CancelReturn,
    ClientGoalHandle,
    GoalResponse,
    GoalStatus,
    ServerGoalHandle,
)
from zenoh_robot.actions.server import STATUS_QOS
from zenoh_robot.ros2 import ros2_action_type
from zenoh_robot.services import ServiceTimeout

pytestmark = pytest.mark.fast   # in-process sessions on loopback only (conftest: the fast tier)

Fibonacci = ros2_action_type("example_interfaces/action/Fibonacci")
WAIT = 10.0


def fibonacci(handle: ServerGoalHandle) -> Any:
    seq = [0, 1]
    for i in range(1, handle.request.order):
        seq.append(seq[i] + seq[i - 1])
        handle.publish_feedback(Fibonacci.Feedback(sequence=list(seq)))
    handle.succeed()
    return Fibonacci.Result(sequence=seq)


class Gate:
    """An execute callback that holds its goal until released (or canceled, if asked)."""

    def __init__(self) -> None:
        self.started = threading.Event()
        self.release = threading.Event()
        self.runs = 0

    def __call__(self, handle: ServerGoalHandle) -> Any:
        self.runs += 1
        self.started.set()
        while not self.release.wait(0.01):
            if handle.is_cancel_requested:
                handle.canceled()
                return Fibonacci.Result(sequence=[-1])
        handle.succeed()
        return Fibonacci.Result(sequence=[handle.request.order])


@pytest.fixture
def nodes(ns: str) -> Iterator[tuple[Node, Node]]:
    with spinning_nodes(ns) as (a, b):
        yield a, b


def _ready(client: Any) -> Any:
    assert client.wait_for_server(WAIT)
    return client


def test_a_goal_gets_feedback_and_its_result(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server = server_node.create_action_server(Fibonacci, "fibonacci", fibonacci)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    feedback: list[list[int]] = []
    handle = client.send_goal_async(Fibonacci.Goal(order=6),
                                    feedback_callback=lambda m: feedback.append(list(m.feedback.sequence))
                                    ).result(WAIT)
    assert handle.accepted and len(handle.goal_id.uuid) == 16
    response = handle.get_result_async().result(WAIT)
    assert response.status == GoalStatus.STATUS_SUCCEEDED
    assert list(response.result.sequence) == [0, 1, 1, 2, 3, 5, 8]
    assert wait_for(lambda: len(feedback) == 5, WAIT), feedback
    assert feedback[-1] == [0, 1, 1, 2, 3, 5, 8]
    assert wait_for(lambda: handle.status == GoalStatus.STATUS_SUCCEEDED, WAIT)   # from the status topic
    assert server.executions == 1
    assert client.send_goal(Fibonacci.Goal(order=2), timeout=WAIT).result.sequence == [0, 1, 1]


def test_the_action_is_five_parts_under_its_name(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server_node.create_action_server(Fibonacci, "fibonacci", fibonacci)
    client_node.create_action_client(Fibonacci, "fibonacci")
    base = server_node.resolve_topic_name("fibonacci")
    keys = {s.key for s in server_node.services}
    assert {f"@srv/{base}/_action/{p}" for p in ("send_goal", "cancel_goal", "get_result")} <= keys
    pubs = {p.key: p for p in server_node.publishers}
    status = pubs[f"{base}/_action/status"]
    assert (status.qos.durability.name, status.qos.history.name, status.qos.depth) == ("TRANSIENT_LOCAL",
                                                                                       "KEEP_LAST", 1)
    assert f"{base}/_action/feedback" in pubs
    subs = {s.key for s in client_node.subscriptions}
    assert {f"{base}/_action/feedback", f"{base}/_action/status"} <= subs


def test_a_rejected_goal_is_reported_and_never_runs(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    runs: list[int] = []

    def execute(handle: ServerGoalHandle) -> Any:
        runs.append(1)
        return fibonacci(handle)
    server = server_node.create_action_server(
        Fibonacci, "fibonacci", execute,
        goal_callback=lambda g: GoalResponse.ACCEPT if g.order < 10 else GoalResponse.REJECT)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handle = client.send_goal_async(Fibonacci.Goal(order=50)).result(WAIT)
    assert not handle.accepted
    with pytest.raises(RuntimeError, match="rejected"):
        handle.get_result_async()
    assert client.send_goal(Fibonacci.Goal(order=50), timeout=WAIT) is None
    assert runs == [] and server.rejected == 2


def test_a_resent_goal_gets_the_same_answer_and_runs_once(nodes: tuple[Node, Node]) -> None:
    """The lossy link's retry: the same goal id sent again (the first reply lost) is the same goal."""
    server_node, client_node = nodes
    gate = Gate()
    server = server_node.create_action_server(Fibonacci, "fibonacci", gate)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    goal_id = uuid.uuid4()
    first = client.send_goal_async(Fibonacci.Goal(order=3), goal_uuid=goal_id).result(WAIT)
    assert gate.started.wait(WAIT)
    again = client.send_goal_async(Fibonacci.Goal(order=3), goal_uuid=goal_id).result(WAIT)
    assert first.accepted and again.accepted
    assert (again.stamp.sec, again.stamp.nanosec) == (first.stamp.sec, first.stamp.nanosec)
    gate.release.set()
    assert again.get_result_async().result(WAIT).result.sequence == [3]
    # Sent once more after the goal finished: still the first answer, still one execution.
    late = client.send_goal_async(Fibonacci.Goal(order=3), goal_uuid=goal_id).result(WAIT)
    assert late.accepted and late.stamp.nanosec == first.stamp.nanosec
    assert gate.runs == 1 and server.executions == 1 and server.duplicates == 2


def test_a_rejected_goal_resent_is_rejected_again(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    answers = iter([GoalResponse.REJECT, GoalResponse.ACCEPT])
    server_node.create_action_server(Fibonacci, "fibonacci", fibonacci, goal_callback=lambda g: next(answers))
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    goal_id = uuid.uuid4()
    assert not client.send_goal_async(Fibonacci.Goal(order=3), goal_uuid=goal_id).result(WAIT).accepted
    assert not client.send_goal_async(Fibonacci.Goal(order=3), goal_uuid=goal_id).result(WAIT).accepted


def test_a_goal_is_canceled_when_the_server_accepts(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    gate = Gate()
    server_node.create_action_server(Fibonacci, "fibonacci", gate,
                                     cancel_callback=lambda h: CancelResponse.ACCEPT)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handle = client.send_goal_async(Fibonacci.Goal(order=3)).result(WAIT)
    assert gate.started.wait(WAIT)
    response = handle.cancel_goal_async().result(WAIT)
    assert response.return_code == CancelReturn.ERROR_NONE
    assert [bytes(g.goal_id.uuid) for g in response.goals_canceling] == [bytes(handle.goal_id.uuid)]
    result = handle.get_result_async().result(WAIT)
    assert result.status == GoalStatus.STATUS_CANCELED and result.result.sequence == [-1]
    # Canceling a finished goal: refused, saying why.
    assert handle.cancel_goal_async().result(WAIT).return_code == CancelReturn.ERROR_GOAL_TERMINATED


def test_cancel_refusals_reach_the_caller(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    gate = Gate()
    server_node.create_action_server(Fibonacci, "fibonacci", gate)     # rclpy's default: cancel rejected
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handle = client.send_goal_async(Fibonacci.Goal(order=3)).result(WAIT)
    assert handle.cancel_goal_async().result(WAIT).return_code == CancelReturn.ERROR_REJECTED
    unknown = client._cancel_goal_async(uuid.uuid4().bytes).result(WAIT)
    assert unknown.return_code == CancelReturn.ERROR_UNKNOWN_GOAL_ID and unknown.goals_canceling == []
    gate.release.set()
    assert handle.get_result_async().result(WAIT).status == GoalStatus.STATUS_SUCCEEDED


def test_cancel_all_goals_with_the_zero_id(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    gate = Gate()
    server_node.create_action_server(Fibonacci, "fibonacci", gate, cancel_callback=lambda h: CancelResponse.ACCEPT)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handles = [client.send_goal_async(Fibonacci.Goal(order=i)).result(WAIT) for i in (1, 2)]
    response = client._cancel_goal_async(bytes(16)).result(WAIT)
    assert response.return_code == CancelReturn.ERROR_NONE and len(response.goals_canceling) == 2
    assert all(h.get_result_async().result(WAIT).status == GoalStatus.STATUS_CANCELED for h in handles)


def test_an_unknown_goal_has_no_result(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server_node.create_action_server(Fibonacci, "fibonacci", fibonacci)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    stranger = ClientGoalHandle(client, uuid.uuid4().bytes, True, None)
    response = stranger.get_result_async().result(WAIT)
    assert response.status == GoalStatus.STATUS_UNKNOWN and response.result.sequence == []


def test_concurrent_goals_are_capped(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    gate = Gate()
    server_node.create_action_server(Fibonacci, "fibonacci", gate, max_goals=2)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    answers = [client.send_goal_async(Fibonacci.Goal(order=i)).result(WAIT).accepted for i in range(3)]
    assert answers == [True, True, False]
    gate.release.set()


def test_results_are_kept_within_bounds(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server = server_node.create_action_server(Fibonacci, "fibonacci", fibonacci, max_results=1)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    first = client.send_goal_async(Fibonacci.Goal(order=1)).result(WAIT)
    assert first.get_result_async().result(WAIT).status == GoalStatus.STATUS_SUCCEEDED
    second = client.send_goal_async(Fibonacci.Goal(order=2)).result(WAIT)
    assert second.get_result_async().result(WAIT).status == GoalStatus.STATUS_SUCCEEDED
    # Only the newest result is kept: the first goal is forgotten, and said to be unknown.
    assert first.get_result_async().result(WAIT).status == GoalStatus.STATUS_UNKNOWN
    assert len(server.goal_handles()) == 1


def test_results_expire_after_the_result_timeout(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server_node.create_action_server(Fibonacci, "fibonacci", fibonacci, result_timeout=0.05)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handle = client.send_goal_async(Fibonacci.Goal(order=1)).result(WAIT)
    handle.get_result_async().result(WAIT)
    assert wait_for(lambda: handle.get_result_async().result(WAIT).status == GoalStatus.STATUS_UNKNOWN, WAIT)


def test_a_failing_execute_callback_aborts_its_goal(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes

    def boom(handle: ServerGoalHandle) -> Any:
        raise RuntimeError("motor fault")

    def forgets(handle: ServerGoalHandle) -> Any:
        return Fibonacci.Result(sequence=[7])      # never said succeed(): rclpy aborts it
    server_node.create_action_server(Fibonacci, "boom", boom)
    server_node.create_action_server(Fibonacci, "forgets", forgets)
    for name, sequence in (("boom", []), ("forgets", [7])):
        client = _ready(client_node.create_action_client(Fibonacci, name))
        response = client.send_goal(Fibonacci.Goal(order=1), timeout=WAIT)
        assert response.status == GoalStatus.STATUS_ABORTED and response.result.sequence == sequence


def test_wrong_types_and_moves_are_refused(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    errors: list[str] = []

    def execute(handle: ServerGoalHandle) -> Any:
        for bad in (lambda: handle.publish_feedback(Fibonacci.Result()), handle.canceled):
            try:
                bad()
            except (TypeError, RuntimeError) as exc:
                errors.append(type(exc).__name__)
        handle.succeed()
        return Fibonacci.Result()
    server_node.create_action_server(Fibonacci, "fibonacci", execute)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    with pytest.raises(TypeError):
        client.send_goal_async(Fibonacci.Result())
    with pytest.raises(ValueError):
        client.send_goal_async(Fibonacci.Goal(), goal_uuid=b"short")
    assert client.send_goal(Fibonacci.Goal(order=1), timeout=WAIT).status == GoalStatus.STATUS_SUCCEEDED
    assert errors == ["TypeError", "RuntimeError"]
    with pytest.raises(TypeError):
        ActionServer(server_node, Fibonacci, "other", "not callable")   # type: ignore[arg-type]


def test_the_zero_goal_id_is_refused(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server = server_node.create_action_server(Fibonacci, "fibonacci", fibonacci)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    assert not client.send_goal_async(Fibonacci.Goal(order=1), goal_uuid=bytes(16)).result(WAIT).accepted
    assert server.executions == 0


def test_a_late_client_reads_the_status_of_finished_goals(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    server_node.create_action_server(Fibonacci, "fibonacci", fibonacci)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handle = client.send_goal_async(Fibonacci.Goal(order=2)).result(WAIT)
    handle.get_result_async().result(WAIT)
    seen: list[Any] = []
    client_node.create_subscription(Fibonacci.goal_status_array, "fibonacci/_action/status", seen.append, STATUS_QOS)
    assert wait_for(lambda: any(s.status == GoalStatus.STATUS_SUCCEEDED for m in seen for s in m.status_list), WAIT)


def test_no_server_no_wait(nodes: tuple[Node, Node]) -> None:
    _, client_node = nodes
    client = client_node.create_action_client(Fibonacci, "nobody")
    assert not client.wait_for_server(0.3)


def test_a_result_not_answered_in_time_is_asked_again(nodes: tuple[Node, Node]) -> None:
    """A goal longer than one get_result wait (or a lost reply): the client asks again, and gets it."""
    server_node, client_node = nodes
    gate = Gate()
    server_node.create_action_server(Fibonacci, "fibonacci", gate)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci", result_poll_s=0.3))
    handle = client.send_goal_async(Fibonacci.Goal(order=4)).result(WAIT)
    result = handle.get_result_async()
    assert wait_for(lambda: client._result.attempts >= 2, WAIT)      # the first wait ran out, asked again
    assert not result.done()
    gate.release.set()
    assert result.result(WAIT).result.sequence == [4] and gate.runs == 1


def test_a_goal_answered_too_late_is_resent_and_runs_once(nodes: tuple[Node, Node]) -> None:
    """The acceptance reply missed the client's deadline (a slow or lossy link): the client sends the same
    goal id again and gets the first decision; the goal runs once."""
    server_node, client_node = nodes
    slow = threading.Event()
    decided: list[int] = []

    def goal_callback(goal: Any) -> GoalResponse:
        decided.append(goal.order)
        slow.wait(WAIT)
        return GoalResponse.ACCEPT
    gate = Gate()
    server = server_node.create_action_server(Fibonacci, "fibonacci", gate, goal_callback=goal_callback)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci", goal_timeout=0.3))
    goal_id = uuid.uuid4()
    with pytest.raises(ServiceTimeout):
        client.send_goal_async(Fibonacci.Goal(order=5), goal_uuid=goal_id).result(WAIT)
    client.goal_timeout = WAIT
    again = client.send_goal_async(Fibonacci.Goal(order=5), goal_uuid=goal_id)
    slow.set()
    handle = again.result(WAIT)
    assert handle.accepted and decided == [5]
    gate.release.set()
    assert handle.get_result_async().result(WAIT).result.sequence == [5]
    assert gate.runs == 1 and server.executions == 1 and server.duplicates == 1


def test_a_resent_cancel_gets_the_same_answer(nodes: tuple[Node, Node]) -> None:
    server_node, client_node = nodes
    gate = Gate()
    asked: list[int] = []

    def cancel_callback(handle: ServerGoalHandle) -> CancelResponse:
        asked.append(1)
        return CancelResponse.ACCEPT

    def stubborn(handle: ServerGoalHandle) -> Any:     # finishes its goal even when asked to cancel
        gate.started.set()
        gate.release.wait(WAIT)
        handle.succeed()
        return Fibonacci.Result(sequence=[1])
    server_node.create_action_server(Fibonacci, "fibonacci", stubborn, cancel_callback=cancel_callback)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci"))
    handle = client.send_goal_async(Fibonacci.Goal(order=1)).result(WAIT)
    assert gate.started.wait(WAIT)
    first = handle.cancel_goal_async().result(WAIT)
    second = handle.cancel_goal_async().result(WAIT)
    assert first.return_code == second.return_code == CancelReturn.ERROR_NONE
    assert len(second.goals_canceling) == 1 and asked == [1]
    assert wait_for(lambda: handle.status == GoalStatus.STATUS_CANCELING, WAIT)
    gate.release.set()
    assert handle.get_result_async().result(WAIT).status == GoalStatus.STATUS_SUCCEEDED


def test_goal_cancel_and_result_cross_half_the_messages_lost(nodes: tuple[Node, Node],
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Half the action's requests and half its replies lost (seeded): with a retry policy the goal, its cancel
    and its result each get through, and the goal runs once. (The lossy-link experiment's real loss is
    docs/lossy-link.md's; here the drop is at the service layer, in process.)"""
    import random

    from zenoh_robot.services import RetryPolicy
    from zenoh_robot.services.client import _Call
    from zenoh_robot.services.service import Service

    rng = random.Random(40)
    lost = {"requests": 0, "replies": 0}
    on_query, on_reply = Service._on_query, _Call.on_reply

    def lossy_query(self: Service[Any, Any], query: Any) -> None:
        if "/_action/" in self.key and rng.random() < 0.5:
            lost["requests"] += 1
            query.drop()
            return
        on_query(self, query)

    def lossy_reply(self: _Call, reply: Any) -> None:
        if "/_action/" in self.client.key and rng.random() < 0.5:
            lost["replies"] += 1
            return
        on_reply(self, reply)
    monkeypatch.setattr(Service, "_on_query", lossy_query)
    monkeypatch.setattr(_Call, "on_reply", lossy_reply)

    server_node, client_node = nodes
    gate = Gate()
    server = server_node.create_action_server(Fibonacci, "fibonacci", gate,
                                              cancel_callback=lambda h: CancelResponse.ACCEPT)
    retry = RetryPolicy(interval_s=0.05, multiplier=1.2, max_interval_s=0.2)
    client = _ready(client_node.create_action_client(Fibonacci, "fibonacci", retry=retry, result_poll_s=5.0))
    handle = client.send_goal_async(Fibonacci.Goal(order=3)).result(WAIT)
    assert handle.accepted and gate.started.wait(WAIT)
    assert handle.cancel_goal_async().result(WAIT).return_code == CancelReturn.ERROR_NONE
    assert handle.get_result_async().result(WAIT).status == GoalStatus.STATUS_CANCELED
    done = client.send_goal_async(Fibonacci.Goal(order=9)).result(WAIT)
    gate.release.set()
    assert done.get_result_async().result(WAIT).result.sequence == [9]
    assert gate.runs == server.executions == 2
    assert lost["requests"] > 0 and lost["replies"] > 0
