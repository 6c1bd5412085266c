"""``-p name:=value`` on command lines: parsing values as YAML reads them, and formatting them back."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import yaml

from .types import InvalidParameterValueError, _scalar_type, infer_type


def parse_param_value(text: str) -> Any:
    """A ``-p`` value as YAML reads it: ``5`` int, ``0.5`` float, ``true`` bool, ``[1, 2]`` list, else str."""
    if text.strip() == "":
        return ""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if value is None:
        return text
    if isinstance(value, dict):
        raise InvalidParameterValueError(f"parameter value {text!r} is a mapping; use one value or a list")
    if isinstance(value, list):
        infer_type(value)  # refuse nested or mixed lists here, with the reason
    elif _scalar_type(value) is None:
        return text   # dates and other YAML extras stay text
    return value


def parse_param_args(argv: Sequence[str]) -> dict[str, Any]:
    """``["-p", "a:=1", "--param", "b:=x", "c:=true"]`` -> ``{"a": 1, "b": "x", "c": True}``."""
    out: dict[str, Any] = {}
    items = list(argv)
    i = 0
    while i < len(items):
        item = items[i]
        if item in ("-p", "--param"):
            if i + 1 >= len(items):
                raise InvalidParameterValueError(f"{item} needs NAME:=VALUE")
            item = items[i + 1]
            i += 1
        elif item.startswith(("-p=", "--param=")):
            item = item.split("=", 1)[1]
        name, sep, value = item.partition(":=")
        if not sep or not name.strip():
            raise InvalidParameterValueError(f"bad parameter argument {item!r}: expected NAME:=VALUE")
        out[name.strip()] = parse_param_value(value)
        i += 1
    return out


def add_param_argument(parser: Any) -> None:
    """Add ``-p/--param NAME:=VALUE`` (repeatable) to an argparse parser; read it with params_from_args."""
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="set a node parameter (repeatable), e.g. -p depth:=5")


def params_from_args(args: Any) -> dict[str, Any]:
    return parse_param_args(getattr(args, "param", None) or [])


def format_param_value(value: Any) -> str:
    """The ``-p`` form of a value (inverse of parse_param_value): strings that would read back
    as something else (``'5'``, ``'true'``, ``''``) are quoted."""
    if isinstance(value, str):
        try:
            same = value != "" and value.strip() == value and parse_param_value(value) == value
        except InvalidParameterValueError:
            same = False
        if same:
            return value
    elif isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return yaml.safe_dump(value, default_flow_style=True, width=1 << 20).strip().removesuffix("...").strip()
