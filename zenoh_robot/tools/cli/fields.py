"""``echo --field a.b``, ``--csv`` and ``--filter EXPR``: pick, flatten and test message fields.

A filter is a Python-like expression over the message's fields, read by a restricted
``ast`` walk: names are fields (``m.`` optional, as in ``m.x > 1``), with literals,
comparisons, ``and``/``or``/``not``, arithmetic, ``abs``/``len`` and ``[i]``. Nothing is
ever ``eval``'d: a call, attribute or name outside the message is refused before the
first sample, so a filter cannot run code.
"""
from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable
from typing import Any

from .main import CliError

_BIN: dict[type[ast.operator], Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
    ast.Mod: operator.mod, ast.FloorDiv: operator.floordiv, ast.Pow: operator.pow}
_CMP: dict[type[ast.cmpop], Callable[[Any, Any], Any]] = {
    ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
    ast.Gt: operator.gt, ast.GtE: operator.ge, ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b}
_FUNCS: dict[str, Callable[..., Any]] = {"abs": abs, "len": len, "min": min, "max": max, "round": round}
MAX_FILTER_CHARS = 500
MAX_POW = 64


class FilterError(CliError):
    pass


def get_path(data: Any, path: str) -> Any:
    """``header.stamp`` or ``gyro.0`` / ``gyro[0]`` in a sample's data; KeyError names the missing part."""
    value = data
    for part in path.replace("[", ".").replace("]", "").split("."):
        if part == "":
            continue
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, (list, tuple)) and part.lstrip("-").isdigit() and -len(value) <= int(part) < len(value):
            value = value[int(part)]
        else:
            fields = ", ".join(value) if isinstance(value, dict) else type(value).__name__
            raise KeyError(f"no field {part!r} in {path!r} (fields: {fields})")
    return value


def flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    """Nested data as ``{"header.seq": 1, "gyro.0": 0.1, ...}`` (the columns of ``--csv``)."""
    out: dict[str, Any] = {}
    if isinstance(data, dict):
        for k, v in data.items():
            out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(data, (list, tuple)):
        for i, v in enumerate(data):
            out.update(flatten(v, f"{prefix}{i}."))
    else:
        out[prefix[:-1]] = f"<{len(data)} bytes>" if isinstance(data, (bytes, bytearray)) else data
    return out


def csv_value(v: Any) -> str:
    text = "" if v is None else str(v)
    return f'"{text.replace(chr(34), chr(34) * 2)}"' if any(c in text for c in ',"\n') else text


class Filter:
    """A compiled ``--filter``: ``Filter("x > 1 and header.seq % 2 == 0")(data) -> bool``."""

    def __init__(self, text: str) -> None:
        if len(text) > MAX_FILTER_CHARS:
            raise FilterError(f"--filter: longer than {MAX_FILTER_CHARS} characters")
        try:
            self.tree = ast.parse(text.strip(), mode="eval").body
        except SyntaxError as exc:
            raise FilterError(f"--filter: not an expression: {exc.msg} in {text!r}") from None
        self.text = text
        self._check(self.tree)

    def _check(self, node: ast.AST) -> None:
        allowed = (ast.BoolOp, ast.UnaryOp, ast.BinOp, ast.Compare, ast.Constant, ast.Name, ast.Attribute,
                   ast.Subscript, ast.Call, ast.List, ast.Tuple, ast.Load, ast.And, ast.Or, ast.Not, ast.USub,
                   ast.UAdd, *_BIN, *_CMP)
        for sub in ast.walk(node):
            if not isinstance(sub, allowed):
                raise FilterError(f"--filter: {type(sub).__name__} is not allowed in {self.text!r} "
                                  "(fields, literals, comparisons, and/or/not, + - * / % **, abs/len/min/max/round)")
            if isinstance(sub, ast.Call) and not (isinstance(sub.func, ast.Name) and sub.func.id in _FUNCS
                                                  and not sub.keywords):
                raise FilterError(f"--filter: only abs, len, min, max, round may be called, in {self.text!r}")
            if isinstance(sub, ast.Attribute) and sub.attr.startswith("_"):
                raise FilterError(f"--filter: no field starts with '_' ({sub.attr!r})")

    def __call__(self, data: Any) -> bool:
        try:
            return bool(self._eval(self.tree, data))
        except (KeyError, TypeError, ValueError, ZeroDivisionError, OverflowError, IndexError):
            return False    # a sample the expression does not fit is not shown

    def _path(self, node: ast.AST) -> str | None:
        if isinstance(node, ast.Name):
            return node.id
        if isinstance(node, ast.Attribute):
            base = self._path(node.value)
            return None if base is None else (node.attr if base == "m" else f"{base}.{node.attr}")
        return None

    def _eval(self, node: ast.AST, data: Any) -> Any:
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, (ast.Name, ast.Attribute)):
            path = self._path(node)
            if path is None:
                raise TypeError("not a field")
            if path in ("True", "False", "None"):
                return {"True": True, "False": False, "None": None}[path]
            if path == "m":
                return data
            return get_path(data, path)
        if isinstance(node, ast.Subscript):
            return self._eval(node.value, data)[self._eval(node.slice, data)]
        if isinstance(node, ast.BoolOp):
            values = (self._eval(v, data) for v in node.values)
            return all(values) if isinstance(node.op, ast.And) else any(values)
        if isinstance(node, ast.UnaryOp):
            v = self._eval(node.operand, data)
            return (not v) if isinstance(node.op, ast.Not) else (-v if isinstance(node.op, ast.USub) else +v)
        if isinstance(node, ast.BinOp):
            a, b = self._eval(node.left, data), self._eval(node.right, data)
            if isinstance(node.op, ast.Pow) and (not isinstance(b, (int, float)) or abs(b) > MAX_POW):
                raise ValueError("exponent too large")
            if isinstance(node.op, ast.Mult) and (isinstance(a, (str, list)) or isinstance(b, (str, list))):
                raise TypeError("no repetition")   # '"x" * 10**9' would eat the memory
            result = _BIN[type(node.op)](a, b)
            if isinstance(result, float) and not math.isfinite(result):
                raise ValueError("not finite")
            return result
        if isinstance(node, ast.Compare):
            left = self._eval(node.left, data)
            for op, right_node in zip(node.ops, node.comparators, strict=True):
                right = self._eval(right_node, data)
                if not _CMP[type(op)](left, right):
                    return False
                left = right
            return True
        if isinstance(node, ast.Call):
            assert isinstance(node.func, ast.Name)
            return _FUNCS[node.func.id](*(self._eval(a, data) for a in node.args))
        if isinstance(node, (ast.List, ast.Tuple)):
            return [self._eval(e, data) for e in node.elts]
        raise TypeError(type(node).__name__)
