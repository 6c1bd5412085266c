"""``zenoh-robot param list|get|set|describe|dump NODE ...``: another node's parameters, remotely.

NODE is the node's fully qualified name (``/uav1/companion``); the node must be spinning.
Changes carry ``--client-id`` (default ``user@host``, the id a GCS uses): a node may accept
some only from one client (the companion: safety limits only from the GCS in control).
"""
from __future__ import annotations

import argparse
import secrets
from typing import Any

import yaml

from zenoh_robot.parameters import (
    InvalidParameterValueError,
    Parameter,
    ParameterClient,
    ParameterType,
    parse_param_value,
)
from zenoh_robot.services import ServiceCallError, ServiceTimeout
from zenoh_robot.session_args import add_session_arguments

from .common import session_config, warn_unreached
from .main import CliError

_LABEL = {ParameterType.BOOL: "Boolean", ParameterType.INTEGER: "Integer", ParameterType.DOUBLE: "Double",
          ParameterType.STRING: "String", ParameterType.BOOL_ARRAY: "Boolean values",
          ParameterType.INTEGER_ARRAY: "Integer values", ParameterType.DOUBLE_ARRAY: "Double values",
          ParameterType.STRING_ARRAY: "String values"}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("param", help="list, get and set a running node's parameters")
    add_session_arguments(p)
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to find and wait for the node (default 3)")
    p.add_argument("--client-id", default=None,
                   help="id sent with changes (default user@host, the GCS's): the node may accept some only "
                        "from the client in control")
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = ops.add_parser("list", help="names of the node's parameters")
    o.add_argument("node", help="fully qualified node name, e.g. /uav1/companion")
    o.add_argument("--prefix", action="append", default=[], help="only names under this prefix")
    o = ops.add_parser("get", help="one parameter's value")
    o.add_argument("node")
    o.add_argument("name")
    o = ops.add_parser("set", help="change one parameter (the node may refuse)")
    o.add_argument("node")
    o.add_argument("name")
    o.add_argument("value", help="YAML scalar or list: 5, 0.5, true, best_effort, [1, 2]")
    o = ops.add_parser("describe", help="type, description and read-only flag of a parameter")
    o.add_argument("node")
    o.add_argument("name")
    o = ops.add_parser("dump", help="every parameter as YAML (a launch file's params: block)")
    o.add_argument("node")
    o = ops.add_parser("load", help="set parameters from a YAML file (ros2's param file, or what dump writes)")
    o.add_argument("node")
    o.add_argument("file", help="YAML: '/node: {ros__parameters: {...}}' ('/**' for any node) or dump's output")
    o = ops.add_parser("delete", help="undeclare a parameter (the node's on-set callbacks must agree)")
    o.add_argument("node")
    o.add_argument("name")
    for op in ops.choices.values():   # the session flags after the operation too, as `topic` takes them
        add_session_arguments(op)
    p.set_defaults(func=run)


def _node_name(text: str) -> str:
    text = text.strip()
    if not text or text == "/":
        raise CliError("NODE must be a node's fully qualified name, e.g. /uav1/companion")
    return text if text.startswith("/") else "/" + text


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.node import Node  # imported late so `zenoh-robot --help` stays fast

    target = _node_name(args.node)
    with Node(f"_zr_param_{secrets.token_hex(3)}", config=session_config(args)) as node:
        warn_unreached(node, args)
        try:
            client = ParameterClient(node, target, timeout=args.timeout, client_id=args.client_id)
        except ValueError as exc:
            raise CliError(f"bad node name {args.node!r}: {exc}") from None
        if not client.wait_for_node(args.timeout):
            raise CliError(f"node {target} not found (no parameter service answered within "
                           f"{args.timeout:g} s; is it running, and on this network?)")
        try:
            return _OPS[args.op](client, target, args)
        except ServiceTimeout:
            raise CliError(f"node {target} does not answer (is it spinning?)") from None
        except ServiceCallError as exc:
            raise CliError(f"node {target}: {exc}") from None


def _list(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    for name in client.list(args.prefix):
        print(f"  {name}")
    return 0


def _get_one(client: ParameterClient, target: str, name: str) -> Parameter:
    (param,) = client.get([name])
    if param is None:
        raise CliError(f"node {target} has no parameter {name!r}")
    return param


def _get(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    param = _get_one(client, target, args.name)
    print(f"{_LABEL.get(param.type_, param.type_.label)} value is: {_show(param.value)}")
    return 0


def _show(value: Any) -> str:
    if isinstance(value, bool):
        return "True" if value else "False"
    return str(value)


def _set(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    (desc,) = client.describe([args.name])
    if desc is None:
        raise CliError(f"node {target} has no parameter {args.name!r}")
    try:
        value = parse_param_value(args.value)
    except InvalidParameterValueError as exc:
        raise CliError(str(exc)) from None
    if desc.type is ParameterType.STRING and not isinstance(value, str):
        value = args.value   # `param set n mode 5` on a string parameter means the text "5"
    try:
        param = Parameter(args.name, value=value)
    except (TypeError, ValueError) as exc:
        raise CliError(f"bad value {args.value!r}: {exc}") from None
    (result,) = client.set([param])
    if not result.successful:
        raise CliError(f"setting parameter {args.name!r} failed: {result.reason}")
    print("Set parameter successful")
    return 0


def _describe(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    (desc,) = client.describe([args.name])
    if desc is None:
        raise CliError(f"node {target} has no parameter {args.name!r}")
    print(f"Parameter name: {desc.name}")
    print(f"  Type: {desc.type.label}")
    if desc.description:
        print(f"  Description: {desc.description}")
    print(f"  Read only: {str(desc.read_only).lower()}")
    return 0


def _dump(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    names = client.list()
    values = {p.name: p.value for p in client.get(names) if p is not None} if names else {}
    print(yaml.safe_dump({target: {"params": values}}, sort_keys=False).rstrip())
    return 0


def _delete(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    (result,) = client.set([Parameter(args.name, ParameterType.NOT_SET)])   # NOT_SET: undeclare (rcl's rule)
    if not result.successful:
        raise CliError(f"deleting parameter {args.name!r} failed: {result.reason}")
    print("Deleted parameter successfully")
    return 0


def _load(client: ParameterClient, target: str, args: argparse.Namespace) -> int:
    values = file_parameters(args.file, target)
    failed = 0
    for name, raw in values.items():
        ok, reason = _set_one(client, target, name, raw)
        print(f"Set parameter {name} successful" if ok else f"Set parameter {name} failed: {reason}")
        failed += not ok
    if failed:
        raise CliError(f"{failed} of {len(values)} parameters from {args.file} not set")
    return 0


def _set_one(client: ParameterClient, target: str, name: str, value: Any) -> tuple[bool, str]:
    (desc,) = client.describe([name])
    if desc is None:
        return False, f"node {target} has no parameter {name!r}"
    if desc.read_only:
        # A dump holds the read-only ones too: loading it back must not fail on a value it keeps.
        (current,) = client.get([name])
        if current is not None and current.value == value:
            return True, ""
    if desc.type is ParameterType.STRING and isinstance(value, (bool, int, float)):
        value = str(value)      # `mode: 5` for a string parameter means the text "5", as `param set` has it
    try:
        param = Parameter(name, value=value)
    except (TypeError, ValueError) as exc:
        return False, f"bad value {value!r}: {exc}"
    (result,) = client.set([param])
    return result.successful, result.reason


def file_parameters(path: str, target: str) -> dict[str, Any]:
    """The parameters a YAML file gives ``target``: dotted names (nested mappings flattened) to values.

    Sections: ``/ns/node``, ``ns/node`` or ``/**`` (every node), each holding ``ros__parameters``
    (ros2) or ``params`` (``param dump``). A node's own section wins over the wildcard's.
    """
    with open(path, encoding="utf-8") as f:
        data = yaml.safe_load(f)
    if not isinstance(data, dict):
        raise CliError(f"{path}: expected a mapping of node names to their parameters")
    out: dict[str, Any] = {}
    matched = False
    for section in ("/**", "**", target.lstrip("/"), target):
        body = data.get(section)
        if body is None:
            continue
        params = body.get("ros__parameters", body.get("params")) if isinstance(body, dict) else None
        if not isinstance(params, dict):
            raise CliError(f"{path}: section {section!r} needs a 'ros__parameters:' (or 'params:') mapping")
        matched = True
        out.update(_flatten(params, ""))
    if not matched:
        raise CliError(f"{path}: no section for {target} (nor '/**'); sections: {', '.join(map(str, data))}")
    return out


def _flatten(mapping: dict[Any, Any], prefix: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


_OPS = {"list": _list, "get": _get, "set": _set, "describe": _describe, "dump": _dump,
        "load": _load, "delete": _delete}
