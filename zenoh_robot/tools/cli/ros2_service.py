"""``zenoh-robot service list|type|find|call --ros2``: the services of ROS 2 nodes (rmw_zenoh's
``SS`` tokens) and calling one with a YAML request, the type found on the graph.

A ROS 2 server announces its service's type and hash in its token, but not the definition: the
call needs the ``.srv`` (``--srv FILE``) unless the type is a standard one known here
(``zenoh_robot.ros2.KNOWN_SERVICES``).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import did_you_mean
from .main import CliError
from .topic import discover_graph
from .values import build_message, parse_values, render_data

if TYPE_CHECKING:
    from zenoh_robot.node import Node
    from zenoh_robot.services import Ros2ServiceInfo


def graph_services(node: "Node") -> list["Ros2ServiceInfo"]:
    """The servers and clients the node's graph subscriber has seen (it keeps SS/SC tokens too)."""
    from zenoh_robot.services import service_infos

    return service_infos(node.graph.other_tokens())


def servers(node: "Node", timeout: float, name: str | None = None) -> list["Ros2ServiceInfo"]:
    """The ROS 2 service servers once discovery settles: until a server (of ``name``, if given) is
    known and no token has come for a quiet spell, at most ``timeout``. One early query may hold only
    part of the tokens; the graph's subscriber keeps taking them as they arrive."""
    def found() -> bool:
        return any(i.kind == "SS" and (name is None or i.service_name == name) for i in graph_services(node))

    discover_graph(node, timeout, found)
    return [i for i in graph_services(node) if i.kind == "SS"]


def node_services(node: "Node", target: str) -> tuple[list[str], list[str]]:
    """``service: type`` lines of the servers and the clients of the node ``target`` (its full name), from
    the graph as discovered (call after ``discover_graph``)."""
    out: dict[str, list[str]] = {"SS": [], "SC": []}
    for info in graph_services(node):
        if f"{info.node_namespace.rstrip('/')}/{info.node_name}" == target:
            out[info.kind].append(f"{info.service_name}: {info.service_type}")
    return out["SS"], out["SC"]


def _list(node: "Node", args: argparse.Namespace) -> int:
    prefix = "/" + args.prefix.strip("/") if args.prefix.strip("/") else ""
    shown: set[tuple[str, str]] = set()
    for info in servers(node, args.timeout):
        if "/_action/" in info.service_name and not args.include_hidden_services:
            continue    # an action's part: `action list` shows the action
        if prefix and not (info.service_name == prefix or info.service_name.startswith(prefix + "/")):
            continue
        shown.add((info.service_name, info.service_type))
    for name, type_name in sorted(shown):
        print(f"{name} [{type_name}]" if args.show_types else name)
    return 0


def _of(node: "Node", name: str, timeout: float) -> list["Ros2ServiceInfo"]:
    infos = servers(node, timeout, name)
    mine = [i for i in infos if i.service_name == name]
    if not mine:
        raise CliError(f"service {name} not found: no ROS 2 server announces it"
                       + did_you_mean(name, {i.service_name for i in infos}))
    return mine


def _type(node: "Node", args: argparse.Namespace) -> int:
    for shown in sorted({i.service_type for i in _of(node, _absolute(args.service), args.timeout)}):
        print(shown)
    return 0


def _find(node: "Node", args: argparse.Namespace) -> int:
    wanted = args.type.strip()
    for name in sorted({i.service_name for i in servers(node, args.timeout)
                        if wanted in (i.service_type, i.service_type.rsplit("/", 1)[-1])}):
        print(name)
    return 0


def _absolute(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def _call(node: "Node", args: argparse.Namespace) -> int:
    from zenoh_robot.ros2 import Ros2TypeError, ros2_service_type
    from zenoh_robot.services import ServiceCallError

    name = _absolute(args.service)
    infos = _of(node, name, args.timeout)
    if any(i.humble for i in infos):
        raise CliError(f"service {name} is served by ROS 2 Humble (no type hash): Humble's rmw_zenoh "
                       "exchanges no data with Jazzy or newer, nor with this tool")
    type_names = sorted({i.service_type for i in infos})
    if len(type_names) > 1:
        raise CliError(f"service {name} is served with several types: {', '.join(type_names)}")
    srv_file = getattr(args, "srv", None)
    try:
        srv = ros2_service_type(type_names[0], Path(srv_file).read_text() if srv_file else None)
    except (Ros2TypeError, OSError) as exc:
        raise CliError(f"{exc} (--srv FILE)") from None
    hashes = {i.type_hash for i in infos}
    if hashes != {srv.hash}:
        raise CliError(f"service {name}: {srv.name} here has hash {srv.hash}, the server's is "
                       f"{', '.join(sorted(hashes))} (another version of the type)")
    request, _ = build_message(srv.request, parse_values(args.request))
    client = node.create_client(name, srv.request, srv.response)
    try:
        response: Any = client.call(request, timeout=args.timeout)
    except ServiceCallError as exc:
        raise CliError(str(exc)) from None
    finally:
        node.destroy_client(client)
    print(render_data(response.to_dict()))
    return 0


OPS = {"list": _list, "call": _call, "type": _type, "find": _find}
