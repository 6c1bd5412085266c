"""Load a ROS ``.msg`` definition at run time into a message type: no build step.

Supports primitives, fixed (``float64[28]``), bounded (``int32[<=5]``) and unbounded
arrays, strings (``string<=10`` too), nested types already known by name (``Header``,
``geometry_msgs/Vector3``, or types loaded earlier), constants (``int8 MODE=1``),
default values (``float64 x 1.5``) and comments.
"""
from __future__ import annotations

import re
from dataclasses import field
from pathlib import Path
from typing import Any

import yaml

from .message import PRIMITIVES, Message, lookup, message, parse_type, type_support

_LINE = re.compile(r"^(?P<type>[A-Za-z][\w/]*(?:<=\d+)?(?:\[(?:<=)?\d*\])?)\s+(?P<name>[A-Za-z]\w*)"
                   r"(?:\s*(?P<eq>=)\s*(?P<const>.+)|\s+(?P<default>.+))?$")
_ALIASES = {"Header": "std_msgs/Header"}


class MsgParseError(ValueError):
    """A .msg definition that cannot be loaded; the message names the line."""


def _strip_comment(line: str) -> str:
    # '#' inside a quoted string constant is not a comment.
    out, quote = [], None
    for ch in line:
        if quote:
            if ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
        elif ch == "#":
            break
        out.append(ch)
    return "".join(out).strip()


def _literal(text: str, where: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        raise MsgParseError(f"{where}: cannot read value {text!r}") from None


def _resolve(name: str) -> type:
    name = _ALIASES.get(name, name)
    try:
        return lookup(name)
    except KeyError as exc:
        raise MsgParseError(str(exc.args[0])) from None


def load_msg(source: str | Path, name: str | None = None, package: str = "msg") -> type[Message]:
    """Parse ``source`` (a path to a .msg file, or its text) into a message type named ``name``."""
    text: str
    if isinstance(source, Path) or (isinstance(source, str) and "\n" not in source and source.endswith(".msg")):
        path = Path(source)
        if not path.is_file():
            raise MsgParseError(f"{path}: no such .msg file")
        text = path.read_text()
        name = name or path.stem
    else:
        text = str(source)
    if not name or not re.match(r"^[A-Za-z]\w*$", name):
        raise MsgParseError(f"a loaded message needs a type name (letters, digits, _), got {name!r}")

    namespace: dict[str, Any] = {"__annotations__": {}, "__module__": f"zenoh_robot.loaded.{package}"}
    constants: dict[str, Any] = {}
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = _strip_comment(raw)
        if not line:
            continue
        where = f"{name}.msg line {lineno}"
        m = _LINE.match(line)
        if not m:
            raise MsgParseError(f"{where}: cannot parse {raw.strip()!r} (expected 'TYPE NAME [DEFAULT]')")
        type_text, fname = m["type"], m["name"]
        try:
            base, arr = parse_type(type_text, resolve=_resolve)
        except ValueError as exc:
            raise MsgParseError(f"{where}: {exc}") from None
        if m["eq"]:
            if arr is not None or not isinstance(base, str):
                raise MsgParseError(f"{where}: constants must be primitive scalars")
            try:
                constants[fname] = PRIMITIVES[base](_literal(m["const"], where))
            except (TypeError, ValueError):
                raise MsgParseError(f"{where}: constant {m['const']!r} is not a valid {base}") from None
            continue
        if fname in namespace["__annotations__"]:
            raise MsgParseError(f"{where}: duplicate field {fname!r}")
        ros = type_text if isinstance(base, str) else type_text.replace(type_text.split("[")[0],
                                                                        type_support(base).name)
        namespace["__annotations__"][fname] = Any
        namespace[fname] = _field(base, arr, ros, m["default"], where)
    cls = type(name, (Message,), namespace)
    cls = message(name=f"{package}/{name}")(cls)
    for cname, value in constants.items():
        setattr(cls, cname, value)
    return cls


def _field(base: str | type, arr: int | None, ros: str, default_text: str | None, where: str) -> Any:
    default = _literal(default_text, where) if default_text is not None else None
    meta = {"ros": ros}
    if arr is None:
        if isinstance(base, type):
            return field(default_factory=base, metadata=meta)
        py = PRIMITIVES[base]
        try:
            value = py(default) if default is not None else {bool: False, int: 0, float: 0.0, str: ""}[py]
        except (TypeError, ValueError):
            raise MsgParseError(f"{where}: default {default_text!r} is not a valid {base}") from None
        return field(default=value, metadata=meta)
    if isinstance(base, str) and base in ("uint8", "byte", "char"):
        init = bytes(default) if default is not None else bytes(max(arr, 0))
        return field(default_factory=lambda: init, metadata=meta)
    if default is not None:
        if not isinstance(default, list) or (arr >= 0 and len(default) != arr):
            raise MsgParseError(f"{where}: default {default_text!r} must be a list of {arr} values")
        return field(default_factory=lambda: list(default), metadata=meta)
    if isinstance(base, type):
        return field(default_factory=lambda: [base() for _ in range(max(arr, 0))], metadata=meta)
    zero = {bool: False, int: 0, float: 0.0, str: ""}[PRIMITIVES[base]]
    return field(default_factory=lambda: [zero] * max(arr, 0), metadata=meta)
