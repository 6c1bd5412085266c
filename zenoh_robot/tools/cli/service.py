"""``zenoh-robot service list|call``: the services on the network, and calling one by name.

``call`` needs no Python types: the server describes its request type and takes the
request as a mapping (``'{altitude: 5.0}'``), answering with a mapping.
"""
from __future__ import annotations

import argparse
import secrets
import time

import yaml

from zenoh_robot.services import SERVICE_PREFIX, ServiceCallError, call_dict, describe_services, service_key
from .common import add_zenoh_arg, zenoh_config
from .main import CliError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("service", help="list and call services")
    add_zenoh_arg(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = ops.add_parser("list", help="services on the network, with their types")
    o.add_argument("prefix", nargs="?", default="", help="only services under this name, e.g. /uav1")
    o.add_argument("-t", "--show-types", action="store_true", help="show request/response types")
    o.add_argument("--timeout", type=float, default=1.5, help="seconds to collect answers (default 1.5)")
    o = ops.add_parser("call", help="call a service with a YAML request")
    o.add_argument("service", help="absolute service name, e.g. /uav1/command (see `service list`)")
    o.add_argument("request", nargs="?", default="{}", help="request fields as YAML, e.g. '{altitude: 5}'")
    o.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the reply (default 5)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.node import Node

    with Node(f"_zr_service_{secrets.token_hex(3)}", config=zenoh_config(args)) as node:
        if args.op == "list":
            return _list(node, args)
        return _call(node, args)


def _list(node, args: argparse.Namespace) -> int:
    time.sleep(0.3)   # let a fresh session learn the network before asking it
    pattern = f"{SERVICE_PREFIX}/**"
    if args.prefix.strip("/"):
        try:
            pattern = service_key("/" + args.prefix.strip("/")) + "/**"
        except ValueError as exc:
            raise CliError(str(exc)) from None
    own = node.fully_qualified_name
    infos = [i for i in describe_services(node.session, pattern, args.timeout) if i.get("node") != own]
    for info in infos:
        if args.show_types:
            print(f"{info['service']} [{info['request']} -> {info['response']}]")
        else:
            print(info["service"])
    return 0


def _call(node, args: argparse.Namespace) -> int:
    try:
        request = yaml.safe_load(args.request) if args.request.strip() else {}
    except yaml.YAMLError as exc:
        raise CliError(f"request is not valid YAML: {exc}".splitlines()[0]) from None
    if request is None:
        request = {}
    if not isinstance(request, dict):
        raise CliError(f"request must be a mapping of field names to values, got {args.request!r}")
    name = args.service if args.service.startswith("/") else "/" + args.service
    try:
        response = call_dict(node, name, request, timeout=args.timeout)
    except ServiceCallError as exc:
        raise CliError(str(exc)) from None
    except ValueError as exc:
        raise CliError(f"bad service name {args.service!r}: {exc}") from None
    print(yaml.safe_dump(response, sort_keys=False, default_flow_style=False).rstrip())
    return 0
