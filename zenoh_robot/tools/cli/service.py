"""``zenoh-robot service list|call``: the services on the network, and calling one by name.

``call`` needs no Python types: the server describes its request type and takes the
request as a mapping (``'{altitude: 5.0}'``), answering with a mapping.
"""
from __future__ import annotations

import argparse
import secrets
import time
from typing import Any

from zenoh_robot.services import SERVICE_PREFIX, ServiceCallError, call_dict, describe_services, service_key
from zenoh_robot.session_args import add_session_arguments

from .common import did_you_mean, lookup_type, session_config, warn_unreached, wire_of
from .main import CliError
from .topic import GRAPH_QUIET, discover_graph
from .values import build_message, parse_values, render_data


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("service", help="list and call services")
    add_session_arguments(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = ops.add_parser("list", help="services on the network, with their types")
    o.add_argument("prefix", nargs="?", default="", help="only services under this name, e.g. /uav1")
    o.add_argument("-t", "--show-types", action="store_true", help="show request/response types")
    o.add_argument("--include-hidden-services", action="store_true",
                   help="also the services of actions (<action>/_action/send_goal, ...), as ros2 service list")
    o.add_argument("--timeout", type=float, default=1.5, help="seconds to collect answers (default 1.5)")
    o = ops.add_parser("call", help="call a service with a YAML request")
    o.add_argument("service", help="absolute service name, e.g. /uav1/command (see `service list`)")
    o.add_argument("request", nargs="?", default="{}", help="request fields as YAML, e.g. '{altitude: 5}'")
    o.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the reply (default 5)")
    o.add_argument("--srv", metavar="FILE", help="with --ros2: the .srv of a service type not known here")
    o = ops.add_parser("type", help="a service's type (X for an X_Request/X_Response pair, else REQ -> RESP)")
    o.add_argument("service", help="absolute service name, e.g. /uav1/command")
    o.add_argument("--timeout", type=float, default=1.5, help="seconds to collect answers (default 1.5)")
    o = ops.add_parser("find", help="services of a type")
    o.add_argument("type", help="service type (zenoh_robot/GetParameters, GetParameters) or its request type")
    o.add_argument("--timeout", type=float, default=1.5, help="seconds to collect answers (default 1.5)")
    for op in ops.choices.values():   # the session flags after the operation too, as `topic` takes them
        add_session_arguments(op)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.node import Node

    wire = wire_of(args)
    with Node(f"_zr_service_{secrets.token_hex(3)}", config=session_config(args), wire=wire) as node:
        warn_unreached(node, args)
        if wire.name == "ros2":
            from .ros2_service import OPS

            return OPS[args.op](node, args)
        return _OPS[args.op](node, args)


def _list(node: Any, args: argparse.Namespace) -> int:
    pattern = f"{SERVICE_PREFIX}/**"
    if args.prefix.strip("/"):
        try:
            pattern = service_key("/" + args.prefix.strip("/")) + "/**"
        except ValueError as exc:
            raise CliError(str(exc)) from None
    for info in _others(node, pattern, args.timeout):
        if hidden_service(str(info["service"])) and not args.include_hidden_services:
            continue
        if args.show_types:
            print(f"{info['service']} [{info['request']} -> {info['response']}]")
        else:
            print(info["service"])
    return 0


def hidden_service(name: str) -> bool:
    """An action's part (``<action>/_action/send_goal``): ``action list`` shows the action instead."""
    return "/_action/" in name


def service_type(info: dict[str, Any]) -> str:
    """``zenoh_robot/GetParameters`` for a ``_Request``/``_Response`` pair, else ``REQ -> RESP``."""
    req, resp = str(info["request"]), str(info["response"])
    if req.endswith("_Request") and resp == req[:-len("_Request")] + "_Response":
        return req[:-len("_Request")]
    return f"{req} -> {resp}"


def _others(node: Any, pattern: str, timeout: float) -> list[dict[str, Any]]:
    """The servers under ``pattern`` but this tool's own, once two answers spaced by a quiet spell agree
    (at most ``timeout``): a fresh session learns the servers over a moment, so one early query may
    reach only some of them."""
    own = node.fully_qualified_name
    end = time.monotonic() + timeout
    discover_graph(node, timeout)
    last: frozenset[tuple[str, str]] | None = None
    while True:
        left = end - time.monotonic()
        infos = [i for i in describe_services(node.session, pattern, max(0.2, min(1.0, left)))
                 if i.get("node") != own]
        seen = frozenset((str(i.get("service")), str(i.get("node"))) for i in infos)
        if seen == last or left <= GRAPH_QUIET:
            return infos
        last = seen
        time.sleep(GRAPH_QUIET)


def _type(node: Any, args: argparse.Namespace) -> int:
    name = _absolute(args.service)
    try:
        key = service_key(name)
    except ValueError as exc:
        raise CliError(f"bad service name {args.service!r}: {exc}") from None
    infos = _others(node, key, args.timeout)
    if not infos:
        known = [i["service"] for i in _others(node, f"{SERVICE_PREFIX}/**", args.timeout)]
        raise CliError(f"service {name} not found: no server answered" + did_you_mean(name, known))
    for shown in sorted({service_type(i) for i in infos}):   # two servers may disagree: show both
        print(shown)
    return 0


def _find(node: Any, args: argparse.Namespace) -> int:
    wanted = args.type.strip()
    short = "/" not in wanted

    def matches(info: dict[str, Any]) -> bool:
        names = {service_type(info), str(info["request"])}
        return wanted in names or (short and any(n.rsplit("/", 1)[-1] == wanted for n in names))

    for name in sorted({i["service"] for i in _others(node, f"{SERVICE_PREFIX}/**", args.timeout) if matches(i)}):
        print(name)
    return 0


def _absolute(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def _call(node: Any, args: argparse.Namespace) -> int:
    request = parse_values(args.request)     # the YAML rules `topic pub` has
    name = _absolute(args.service)
    try:
        request = _coerced(node, service_key(name), request, args.timeout)
        response = call_dict(node, name, request, timeout=args.timeout)
    except ServiceCallError as exc:
        raise CliError(str(exc)) from None
    except ValueError as exc:
        raise CliError(f"bad service name {args.service!r}: {exc}") from None
    print(render_data(response))
    return 0


def _coerced(node: Any, key: str, request: dict[str, Any], timeout: float) -> dict[str, Any]:
    """The request through values.build_message when its type is known here (same name and hash):
    `{altitude: 5}` reaches the server as 5.0 for a float64, and a mistake is one line before the
    call. A type known only to the server goes as given; the server checks it against its schema."""
    from zenoh_robot.message import type_support

    infos = describe_services(node.session, key, timeout=min(timeout, 2.0))
    if not infos:
        return request          # call_dict says "no server"
    try:
        cls = lookup_type(str(infos[0]["request"]))
    except CliError:
        return request
    if type_support(cls).hash != infos[0].get("request_hash"):
        return request
    msg, _ = build_message(cls, request)
    data: dict[str, Any] = msg.to_dict()
    return data


_OPS = {"list": _list, "call": _call, "type": _type, "find": _find}
