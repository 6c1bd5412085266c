"""``zenoh-robot interface list|show``: the message types this installation knows, field by field.

Known types: the library's standard messages (zenoh_robot.msgs), its parameter service types,
the applications' messages found through the ``zenoh_robot.messages`` entry-point group (the
drone's VehicleState, Command, ...), and any ``.msg`` file given by path. ``show`` prints a type
as ``ros2 interface show`` does: one ``TYPE NAME [DEFAULT]`` line per field, nested message types
expanded below their field, indented by a tab. A service is a ``X_Request``/``X_Response`` pair:
``show X`` prints the request, ``---``, then the response.
"""
from __future__ import annotations

import argparse
import dataclasses
import re
from typing import TYPE_CHECKING, Any

from .common import did_you_mean, is_msg_file, load_msg_file, lookup_type, quiet_exit, ros2_lookup
from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.message import Message

_REQ, _RESP = "_Request", "_Response"
_CONSTANT = re.compile(r"^[A-Za-z0-9_/]+\s+[A-Z][A-Z0-9_]*\s*=")   # `uint8 NUM_JOINTS=28`
_MAX_SHOWN_ARRAY = 8           # a longer default array prints as its length: 28 zeros say nothing


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("interface", help="list the message types known here and show their fields")
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = ops.add_parser("list", help="every known message and service type")
    o.add_argument("-m", "--only-msgs", action="store_true", help="only message types")
    o.add_argument("-s", "--only-srvs", action="store_true", help="only service types")
    o = ops.add_parser("show", help="a type's fields with ROS types and defaults, nested types expanded")
    o.add_argument("type", help="Setpoint, std_msgs/String, zenoh_robot/GetParameters (a service), or FILE.msg")
    o.add_argument("--no-expand", action="store_true", help="do not expand nested message types")
    o.add_argument("--ros2", action="store_true",
                   help="a ROS 2 type (std_msgs/msg/String, example_interfaces/srv/AddTwoInts, "
                        "example_interfaces/action/Fibonacci), as ROS 2 nodes send it")
    p.set_defaults(func=run)


@quiet_exit
def run(args: argparse.Namespace) -> int:
    return _list(args) if args.op == "list" else _show(args)


def known_types() -> dict[str, type[Message]]:
    """Every registered message type by full name (the library's, and the entry points')."""
    from zenoh_robot import msgs  # noqa: F401  importing msgs registers the standard types
    from zenoh_robot.message import _REGISTRY  # no public iterator; read-only here
    from zenoh_robot.parameters import service  # noqa: F401  the parameter services' types

    lookup_type("std_msgs/String")        # loads the entry-point message modules once
    # The registry keeps each type under its full and its short name: the full one is _type_name.
    return {cls._type_name: cls for cls in list(_REGISTRY.values())}


def _services(types: dict[str, type[Message]]) -> list[str]:
    return sorted(name[:-len(_REQ)] for name in types
                  if name.endswith(_REQ) and name[:-len(_REQ)] + _RESP in types)


def _list(args: argparse.Namespace) -> int:
    types = known_types()
    services = _services(types)
    in_services = {s + suffix for s in services for suffix in (_REQ, _RESP)}
    if not args.only_srvs:
        print("Messages:")
        for name in sorted(set(types) - in_services):
            print(f"    {name}")
    if not args.only_msgs:
        print("Services:")
        for name in services:
            print(f"    {name}")
    return 0


def _show(args: argparse.Namespace) -> int:
    name = args.type
    if getattr(args, "ros2", False) and not is_msg_file(name):
        print("\n".join(_ros2_lines(name, not args.no_expand)))
        return 0
    if is_msg_file(name):
        constants = [line for line in _msg_lines(name) if _CONSTANT.match(line)]
        print("\n".join([*constants, *render(load_msg_file(name), expand=not args.no_expand)]))
        return 0
    types = known_types()
    services = _services(types)
    service = next((s for s in services if name in (s, s.rsplit("/", 1)[-1])), None)
    if service is not None:
        lines = [*render(types[service + _REQ], not args.no_expand), "---",
                 *render(types[service + _RESP], not args.no_expand)]
        print("\n".join(lines))
        return 0
    try:
        cls = lookup_type(name)
    except CliError:
        near = [*types, *services, *{t.rsplit("/", 1)[-1] for t in types}]
        raise CliError(f"unknown interface {name!r}" + did_you_mean(name, near)
                       + " (see `zenoh-robot interface list`)") from None
    print("\n".join(render(cls, expand=not args.no_expand)))
    return 0


def _ros2_lines(name: str, expand: bool) -> list[str]:
    """A ROS 2 message type's fields, a service's request ``---`` response (its type hash last), or an
    action's goal ``---`` result ``---`` feedback (its parts' hashes last)."""
    from zenoh_robot.message import type_support

    if "/srv/" in name:
        from zenoh_robot.ros2 import Ros2TypeError, ros2_service_type

        try:
            srv = ros2_service_type(name)
        except Ros2TypeError as exc:
            raise CliError(str(exc)) from None
        return [*render(srv.request, expand), "---", *render(srv.response, expand), f"# {srv.hash}"]
    if "/action/" in name:
        from zenoh_robot.ros2 import Ros2TypeError, ros2_action_type

        try:
            action = ros2_action_type(name)
        except Ros2TypeError as exc:
            raise CliError(str(exc)) from None
        # As ros2 interface show: goal --- result --- feedback; then the hashes its parts travel with.
        return [*render(action.goal, expand), "---", *render(action.result, expand), "---",
                *render(action.feedback, expand), f"# send_goal {action.send_goal.hash}",
                f"# get_result {action.get_result.hash}", f"# feedback {type_support(action.feedback_message).hash}"]
    cls = ros2_lookup(name)
    return [*render(cls, expand), f"# {type_support(cls).hash}"]


def render(cls: type[Message], expand: bool = True, depth: int = 0) -> list[str]:
    """``ros2 interface show``'s lines for a type's fields; nested types indented by a tab."""
    indent = "\t" * depth
    lines: list[str] = []
    defaults: dict[str, Any] = {}
    if dataclasses.is_dataclass(cls):   # always (@message makes one); the check tells the type checker so
        defaults = {f.name: _default(f) for f in dataclasses.fields(cls)}
    for spec in cls._fields_spec:
        line = f"{indent}{spec.ros_type()} {spec.name}"
        default = defaults.get(spec.name)
        if not spec.is_message and default is not None and _worth_showing(default):
            line += f" {_literal(default)}"
        lines.append(line)
        if expand and not isinstance(spec.base, str):   # a nested message (spec.is_message)
            lines.extend(render(spec.base, expand, depth + 1))
    return lines


def _msg_lines(path: str) -> list[str]:
    # Constants keep their declared type only in the file (msg_loader makes them plain attributes).
    return [line.split("#", 1)[0].strip() for line in open(path, encoding="utf-8")]


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        try:
            return f.default_factory()
        except Exception:     # a factory building a nested message: nothing to print for it
            return None
    return None


def _worth_showing(value: Any) -> bool:
    if isinstance(value, (bytes, bytearray)):
        return 0 < len(value) <= _MAX_SHOWN_ARRAY
    if isinstance(value, (list, tuple)):
        return 0 < len(value) <= _MAX_SHOWN_ARRAY and all(isinstance(v, (bool, int, float, str)) for v in value)
    return isinstance(value, (bool, int, float, str))


def _literal(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value) if value == "" or value.strip() != value or " " in value else value
    if isinstance(value, (bytes, bytearray)):
        value = list(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_literal(v) for v in value) + "]"
    return repr(value)
