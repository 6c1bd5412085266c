"""``zenoh-robot node list|info``: the nodes on the network and what each publishes, subscribes and serves.

Nodes, publishers and subscriptions come from the graph's liveliness tokens (zenoh_robot.graph);
services from the ``zr_describe`` answer every server gives (services.describe_services), which
names the serving node; actions from their feedback topics (action.py), their five parts not listed
one by one. Clients announce nothing on the network, so ``info`` cannot list them
(it says so rather than print an empty list that would look like "none").
"""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from zenoh_robot.session_args import add_session_arguments

from .action import ACTION_INFIX
from .common import HIDDEN_PREFIX, cli_node, did_you_mean, is_ros2, quiet_exit
from .main import CliError
from .reader import shown_type
from .topic import discover_graph

if TYPE_CHECKING:
    from zenoh_robot.graph import TopicEndpointInfo
    from zenoh_robot.node import Node


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("node", help="list nodes and show what a node publishes, subscribes and serves")
    add_session_arguments(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = ops.add_parser("list", help="nodes on the network (fully qualified names)")
    add_session_arguments(o)
    _graph_args(o)
    o.add_argument("-c", "--count-nodes", action="store_true", help="print only the number of nodes")
    o = ops.add_parser("info", help="a node's publishers, subscriptions, services and parameter count")
    add_session_arguments(o)
    o.add_argument("node", help="fully qualified node name, e.g. /uav1/companion")
    _graph_args(o)
    o.add_argument("--no-params", action="store_true", help="skip asking the node for its parameters")
    p.set_defaults(func=run)


def _graph_args(o: argparse.ArgumentParser) -> None:
    o.add_argument("-a", "--all", action="store_true", help="include the CLI tools' own nodes (_zr_...)")
    o.add_argument("--timeout", type=float, default=3.0, help="at most this many seconds to learn the graph")


@quiet_exit
def run(args: argparse.Namespace) -> int:
    with cli_node("node", args) as node:
        return _list(node, args) if args.op == "list" else _info(node, args)


def fqn(namespace: str, name: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"


def node_names(node: "Node", show_all: bool) -> list[str]:
    own = node.fully_qualified_name
    return sorted({fqn(ns, name) for name, ns in node.get_node_names_and_namespaces()
                   if (show_all or not name.startswith(HIDDEN_PREFIX)) and fqn(ns, name) != own})


def _list(node: "Node", args: argparse.Namespace) -> int:
    discover_graph(node, args.timeout)
    names = node_names(node, args.all)
    if args.count_nodes:
        print(len(names))
        return 0
    for name in names:
        print(name)
    return 0


def _target(text: str) -> str:
    text = text.strip()
    if not text.strip("/"):
        raise CliError("NODE must be a node's fully qualified name, e.g. /uav1/companion")
    return text if text.startswith("/") else "/" + text


def _info(node: "Node", args: argparse.Namespace) -> int:
    target = _target(args.node)
    discover_graph(node, args.timeout, lambda: target in node_names(node, True))
    if target not in node_names(node, True):
        raise CliError(f"node {target} not found" + did_you_mean(target, node_names(node, args.all)))
    pubs, subs = _endpoints_of(node, target)
    print(target)
    # An action's five parts are shown as the action (ros2 node info hides them likewise).
    _section("Subscribers", [f"{e.topic_name}: {shown_type(e.topic_type)}" for e in subs if not _hidden(e.topic_name)])
    _section("Publishers", [f"{e.topic_name}: {shown_type(e.topic_type)}" for e in pubs if not _hidden(e.topic_name)])
    if is_ros2(node):      # ROS 2 nodes announce servers and clients (SS/SC tokens), not parameters here
        from .ros2_service import node_services

        servers, clients = node_services(node, target)
        _section("Service Servers", [s for s in servers if not _hidden(s)])
        _section("Service Clients", [c for c in clients if not _hidden(c)])
        _actions(node, target)
        return 0
    _section("Service Servers", [f"{s['service']}: {s['request']} -> {s['response']}"
                                 for s in _services_of(node, target, args.timeout) if not _hidden(s["service"])])
    print("  Service Clients: not announced on the network")
    _actions(node, target)
    if not args.no_params:
        print(f"  Parameters: {_parameter_count(node, target, args.timeout)}")
    return 0


def _hidden(name: str) -> bool:
    return ACTION_INFIX in name


def _actions(node: "Node", target: str) -> None:
    from .action import node_actions

    servers, clients = node_actions(node, target)
    _section("Action Servers", servers)
    _section("Action Clients", clients)


def _section(title: str, lines: list[str]) -> None:
    print(f"  {title}:")
    for line in sorted(set(lines)):
        print(f"    {line}")


def _endpoints_of(node: "Node", target: str) -> tuple[list["TopicEndpointInfo"], list["TopicEndpointInfo"]]:
    from zenoh_robot.graph import EndpointType

    mine = [e for e in node.graph.endpoints() if fqn(e.node_namespace, e.node_name) == target]
    return ([e for e in mine if e.endpoint_type is EndpointType.PUBLISHER],
            [e for e in mine if e.endpoint_type is EndpointType.SUBSCRIPTION])


def _services_of(node: "Node", target: str, timeout: float) -> list[dict[str, str]]:
    from zenoh_robot.services import describe_services

    return [{k: str(v) for k, v in info.items()}
            for info in describe_services(node.session, timeout=min(timeout, 1.5)) if info.get("node") == target]


def _parameter_count(node: "Node", target: str, timeout: float) -> str:
    from zenoh_robot.parameters import ParameterClient
    from zenoh_robot.services import ServiceCallError

    client = ParameterClient(node, target, timeout=min(timeout, 2.0))
    try:
        return str(len(client.list()))
    except ServiceCallError as exc:
        return f"unknown ({exc})"
