"""``zenoh-robot action list|info|type|send_goal``: actions on the network, as ``ros2 action`` shows them.

An action is found by its feedback topic (``<name>/_action/feedback``), whose publishers are the
action's servers and whose subscribers its clients, on either wire: the graph carries topics on
both, and the topic's type (``pkg/action/Name_FeedbackMessage``) names the action's type. ``send_goal``
needs the action's definition: a bundled one (``zenoh_robot.ros2.KNOWN_ACTIONS``), else
``--action FILE`` (the ``.action`` text).
"""
from __future__ import annotations

import argparse
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zenoh_robot.session_args import add_session_arguments

from .common import HIDDEN_PREFIX, cli_node, did_you_mean, quiet_exit
from .main import CliError
from .topic import discover_graph
from .values import build_message, parse_values, render_data

if TYPE_CHECKING:
    from zenoh_robot.node import Node

ACTION_INFIX = "/_action/"
FEEDBACK_SUFFIX = "/_action/feedback"
FEEDBACK_TYPE_SUFFIX = "_FeedbackMessage"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("action", help="list actions, show their servers and clients, send a goal")
    add_session_arguments(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = ops.add_parser("list", help="actions on the network")
    o.add_argument("-t", "--show-types", action="store_true", help="show each action's type")
    o.add_argument("-c", "--count-actions", action="store_true", help="print only the number of actions")
    _graph_args(o)
    o = ops.add_parser("info", help="an action's servers and clients")
    o.add_argument("action_name", help="absolute action name, e.g. /fibonacci")
    o.add_argument("-t", "--show-types", action="store_true", help="show the action's type by each node")
    _graph_args(o)
    o = ops.add_parser("type", help="an action's type")
    o.add_argument("action_name", help="absolute action name, e.g. /fibonacci")
    _graph_args(o)
    o = ops.add_parser("send_goal", help="send a goal and wait for its result")
    o.add_argument("action_name", help="absolute action name, e.g. /fibonacci")
    o.add_argument("action_type", help="the action's type, e.g. example_interfaces/action/Fibonacci")
    o.add_argument("goal", nargs="?", default="{}", help="goal fields as YAML, e.g. '{order: 5}'")
    o.add_argument("-f", "--feedback", action="store_true", help="print the goal's feedback as it comes")
    o.add_argument("--action", metavar="FILE", dest="action_file", help="the .action of a type not known here")
    o.add_argument("--timeout", type=float, default=10.0,
                   help="seconds to wait for a server and for the goal's acceptance (default 10)")
    for op in ops.choices.values():   # the session flags after the operation too, as `topic` takes them
        add_session_arguments(op)
    p.set_defaults(func=run)


def _graph_args(o: argparse.ArgumentParser) -> None:
    o.add_argument("--timeout", type=float, default=3.0, help="at most this many seconds to learn the graph")


@quiet_exit
def run(args: argparse.Namespace) -> int:
    with cli_node("action", args) as node:
        return _OPS[args.op](node, args)


# -- the graph -----------------------------------------------------------------------------------------
@dataclass
class ActionInfo:
    name: str
    types: set[str] = field(default_factory=set)
    servers: set[tuple[str, str]] = field(default_factory=set)    # (node, type)
    clients: set[tuple[str, str]] = field(default_factory=set)


def action_type_of(feedback_type: str) -> str:
    """``pkg/action/Name`` of a feedback topic's ``pkg/action/Name_FeedbackMessage`` (else as given)."""
    return feedback_type[:-len(FEEDBACK_TYPE_SUFFIX)] if feedback_type.endswith(FEEDBACK_TYPE_SUFFIX) \
        else feedback_type


def graph_actions(node: "Node", show_all: bool = False) -> dict[str, ActionInfo]:
    """Every action the node's graph knows, by name (call after ``discover_graph``)."""
    from zenoh_robot.graph import EndpointType

    own = node.fully_qualified_name
    found: dict[str, ActionInfo] = {}
    for e in node.graph.endpoints():
        topic = "/" + e.topic_name.lstrip("/")
        if not topic.endswith(FEEDBACK_SUFFIX):
            continue
        who = f"{e.node_namespace.rstrip('/')}/{e.node_name}"
        if who == own or (not show_all and e.node_name.startswith(HIDDEN_PREFIX)):
            continue
        info = found.setdefault(topic[:-len(FEEDBACK_SUFFIX)], ActionInfo(topic[:-len(FEEDBACK_SUFFIX)]))
        kind = action_type_of(e.topic_type)
        info.types.add(kind)
        (info.servers if e.endpoint_type is EndpointType.PUBLISHER else info.clients).add((who, kind))
    return found


def node_actions(node: "Node", target: str) -> tuple[list[str], list[str]]:
    """``name: type`` lines of the action servers and clients of the node ``target`` (its full name)."""
    servers, clients = [], []
    for info in graph_actions(node, show_all=True).values():
        servers += [f"{info.name}: {kind}" for who, kind in info.servers if who == target]
        clients += [f"{info.name}: {kind}" for who, kind in info.clients if who == target]
    return servers, clients


def _absolute(name: str) -> str:
    name = name.strip()
    if not name.strip("/"):
        raise CliError("ACTION must be an action's name, e.g. /fibonacci")
    return "/" + name.strip("/")


def _one(node: "Node", args: argparse.Namespace) -> ActionInfo:
    name = _absolute(args.action_name)
    discover_graph(node, args.timeout, lambda: name in graph_actions(node))
    actions = graph_actions(node)
    if name not in actions:
        raise CliError(f"action {name} not found: no server or client announces it"
                       + did_you_mean(name, actions))
    return actions[name]


def _list(node: "Node", args: argparse.Namespace) -> int:
    discover_graph(node, args.timeout)
    actions = graph_actions(node)
    if args.count_actions:
        print(len(actions))
        return 0
    for name in sorted(actions):
        print(f"{name} [{', '.join(sorted(actions[name].types))}]" if args.show_types else name)
    return 0


def _info(node: "Node", args: argparse.Namespace) -> int:
    info = _one(node, args)
    print(f"Action: {info.name}")
    for title, members in (("Action clients", info.clients), ("Action servers", info.servers)):
        print(f"{title}: {len(members)}")
        for who, kind in sorted(members):
            print(f"    {who} [{kind}]" if args.show_types else f"    {who}")
    return 0


def _type(node: "Node", args: argparse.Namespace) -> int:
    for kind in sorted(_one(node, args).types):    # two nodes may disagree: show both
        print(kind)
    return 0


# -- send_goal ----------------------------------------------------------------------------------------------
def _action_type(name: str, path: str | None) -> Any:
    from zenoh_robot.ros2 import Ros2TypeError, ros2_action_type

    try:
        return ros2_action_type(name, Path(path).read_text() if path else None)
    except (Ros2TypeError, OSError) as exc:
        raise CliError(f"{exc} (--action FILE)") from None


def _send_goal(node: "Node", args: argparse.Namespace) -> int:
    from zenoh_robot.actions import GoalStatus
    from zenoh_robot.services import ServiceCallError

    if not args.timeout > 0:
        raise CliError(f"--timeout must be > 0 seconds, got {args.timeout:g}")
    action = _action_type(args.action_type, args.action_file)
    goal, _ = build_message(action.goal, parse_values(args.goal))
    name = _absolute(args.action_name)
    spinner = threading.Thread(target=node.spin, daemon=True)     # feedback comes on the node's executor
    spinner.start()
    client = node.create_action_client(action, name, goal_timeout=args.timeout)
    printed = threading.Lock()

    def show(title: str, data: Any) -> None:
        with printed:
            print(f"{title}:\n{_indented(render_data(data))}\n", flush=True)

    if not client.server_is_ready():
        print("Waiting for an action server to become available...", flush=True)
        if not client.wait_for_server(args.timeout):
            raise CliError(f"action {name}: no server within {args.timeout:g} s")
    show("Sending goal", goal.to_dict())
    announced = threading.Event()     # feedback may come before the acceptance: shown after it
    finished = threading.Event()      # ... and none after the result

    def on_feedback(msg: Any) -> None:
        announced.wait(args.timeout)
        if not finished.is_set():
            show("Feedback", msg.feedback.to_dict())
    feedback = on_feedback if args.feedback else None
    try:
        handle = client.send_goal_async(goal, feedback_callback=feedback).result(args.timeout + 2.0)
        if not handle.accepted:
            print("Goal was rejected.")
            return 1
        with printed:
            print(f"Goal accepted with ID: {handle.goal_id_text}\n", flush=True)
        announced.set()
        response = handle.get_result_async().result()
    except ServiceCallError as exc:
        raise CliError(str(exc)) from None
    except TimeoutError:
        raise CliError(f"action {name}: no answer to the goal within {args.timeout:g} s") from None
    # The result's reply completes on a Zenoh thread, the feedback on the executor: feedback that arrived
    # before the result is queued there already, so calls queued behind it mark where it ends (a few
    # rounds: a subscription's drain may hand the rest of its samples back to the end of the queue).
    _after_queued_work(node, rounds=3, timeout=2.0)
    with printed:
        finished.set()
    show("Result", response.result.to_dict())
    status = GoalStatus(response.status).name.removeprefix("STATUS_") \
        if response.status in {s.value for s in GoalStatus} else str(response.status)
    print(f"Goal finished with status: {status}")
    return 0 if response.status == GoalStatus.STATUS_SUCCEEDED else 1


def _after_queued_work(node: Any, rounds: int, timeout: float) -> None:
    """Return once the node's executor has run what was queued before, ``rounds`` times over."""
    done = threading.Event()
    left = [rounds]

    def mark() -> None:
        left[0] -= 1
        if left[0] <= 0 or not node.executor.call_soon(mark):
            done.set()
    if node.executor.call_soon(mark):
        done.wait(timeout)


def _indented(text: str) -> str:
    return "\n".join("    " + line for line in text.splitlines())


_OPS = {"list": _list, "info": _info, "type": _type, "send_goal": _send_goal}
