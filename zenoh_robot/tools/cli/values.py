"""Message values on the command line: YAML in (``pub``), YAML/fields/CSV out (``echo``).

The one coercion from YAML values to a message's field types in the tools: ``pub`` and
anything else building a message from text go through :func:`build_message`.
"""
from __future__ import annotations

import json
from typing import Any

import yaml

from zenoh_robot.message import Message, type_support

from .common import one_line
from .main import CliError
from .reader import RawSample


def to_data(value: Any) -> Any:
    """A sample as plain data: a message's dict, a frame's summary, a raw sample's fields."""
    if isinstance(value, RawSample):
        return {"type": value.type_name, "raw_fields": value.body}   # in declaration order
    return value.to_dict()


def _plain(value: Any, no_arr: bool) -> Any:
    """Message data as YAML-safe values: bytes as their size, arrays as their length with --no-arr."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return f"<{len(value)} bytes>"
    if isinstance(value, dict):
        return {k: _plain(v, no_arr) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return f"<array, length: {len(value)}>" if no_arr else [_plain(v, no_arr) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)     # anything else (a numpy scalar, say) would stop safe_dump


def render_line(data: Any, no_arr: bool = False) -> str:
    """One value on one line (``echo --field``): a string as it is, a structure in YAML's flow style.
    A line per message needs no ``---`` between messages, and a shell loop or ``sort`` reads it as is."""
    if isinstance(data, str):
        return data if "\n" not in data and data.strip() == data else json.dumps(data)
    if isinstance(data, (dict, list, tuple, bytes, bytearray, memoryview)):
        return yaml.safe_dump(_plain(data, no_arr), sort_keys=False, allow_unicode=True, default_flow_style=True,
                              width=1 << 16).strip()
    return f"{data}"


def render_sample(value: Any, no_arr: bool = False) -> str:
    return render_data(to_data(value), no_arr)


def render_data(data: Any, no_arr: bool = False) -> str:
    return yaml.safe_dump(_plain(data, no_arr), sort_keys=False, allow_unicode=True,
                          default_flow_style=False).rstrip()


# -- building a message from YAML ------------------------------------------------------------
_INTEGERS = frozenset({"byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"})


def parse_values(text: str) -> dict[str, Any]:
    try:
        data = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise CliError(one_line(f"values are not valid YAML: {problem}{where}")) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise CliError(f"values must be a YAML mapping of field names to values, e.g. '{{data: hello}}'; "
                       f"got {one_line(text)!r}")
    return data


def _coerce_scalar(base: str, value: Any, where: str) -> Any:
    if base == "bool" and isinstance(value, bool):
        return value
    if base in _INTEGERS and isinstance(value, int) and not isinstance(value, bool):
        return value
    if base in ("float32", "float64") and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if base in ("string", "wstring") and isinstance(value, str):
        return value
    raise CliError(f"{where}: expected {base}, got {type(value).__name__} {value!r}")


def _coerce_field(spec: Any, value: Any, where: str) -> Any:
    """YAML's value as the field's Python type, so receivers never meet a str for a float."""
    if spec.is_bytes:
        if isinstance(value, (bytes, bytearray)):
            return bytes(value)
        if isinstance(value, list) and all(isinstance(v, int) and 0 <= v <= 255 for v in value):
            return bytes(value)
        raise CliError(f"{where}: expected a list of bytes (0..255), got {value!r}")
    if spec.array is not None:
        if not isinstance(value, (list, tuple)):
            raise CliError(f"{where}: expected a list ({spec.ros_type()}), got {value!r}")
        return [_coerce_scalar(spec.base, v, f"{where}[{i}]") for i, v in enumerate(value)]
    return _coerce_scalar(spec.base, value, where)


def check_fields(msg: Any) -> None:
    for spec in msg._fields_spec:
        value = getattr(msg, spec.name)
        where = f"{type_support(type(msg)).name}.{spec.name}"
        if spec.is_message:
            for item in (value if spec.array is not None else [value]):
                check_fields(item)
        else:
            setattr(msg, spec.name, _coerce_field(spec, value, where))


def build_message(cls: type[Message], data: dict[str, Any]) -> tuple[Any, bool]:
    """The message, and whether its header is to be stamped at each publish (``header: auto``)."""
    auto_header = data.get("header") == "auto" and any(s.name == "header" for s in cls._fields_spec)
    if auto_header:
        data = {k: v for k, v in data.items() if k != "header"}
    try:
        msg = cls.from_dict(data)
    except (TypeError, ValueError) as exc:
        raise CliError(one_line(str(exc))) from None
    check_fields(msg)
    try:
        type_support(cls).encode(msg)   # the checks only encoding makes (a fixed array's length), before a session
    except (TypeError, ValueError) as exc:
        raise CliError(one_line(str(exc))) from None
    return msg, auto_header


def flow(msg: Any) -> str:
    """The message on one line: ``{data: hello}``."""
    return yaml.safe_dump(_plain(msg.to_dict(), False), default_flow_style=True, sort_keys=False,
                          width=1 << 16).strip()


