"""Field validation of received message bodies: nothing a peer sends reaches a callback unchecked.

A body is a msgpack array of field values; msgpack alone would hand a callback a
``str`` where the schema says ``float64``, a ``float`` where it says ``bool``, a
4-element list for a ``float32[3]``. Each message type compiles one checker per field
from its :class:`~zenoh_robot.message.FieldSpec` (once, at class creation), and
``_from_wire`` runs them all: a value that does not conform raises
:class:`ValidationError` naming the field path (``Setpoint.header.stamp``), which the
subscription counts as malformed and a service answers as a bad request.

The rules, per ROS type:

* ``bool``: exactly ``True``/``False`` (an int is not a bool, and a bool is not an int).
* integer types: an ``int`` within the type's range (``uint8`` 0..255, ``int64`` ...).
* ``float32``/``float64``: a float (NaN and +-inf included: they are floats) or an int,
  converted to float.
* ``string``: a ``str`` of at most :data:`MAX_STRING_LEN` characters.
* ``uint8[]``/``byte[]``/``char[]``: ``bytes`` (or a list of 0..255, as numpy arrays
  serialise), at most :data:`MAX_BYTES_LEN`; fixed arrays have exactly their length.
* other arrays: a list of at most :data:`MAX_SEQUENCE_LEN` elements (exactly n for
  ``T[n]``), each checked as above.
* nested messages: that type's own ``_from_wire``.

The limits are module attributes so a deployment with bigger messages can raise them;
the payload size limit of a subscription bounds a sample as a whole anyway.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..message import FieldSpec

MAX_STRING_LEN = 1 << 20          # characters in one string field
MAX_SEQUENCE_LEN = 1 << 20        # elements in one unbounded array field
MAX_BYTES_LEN = 256 << 20         # bytes in one uint8[] field (a sample is bounded below this)

INT_RANGES: dict[str, tuple[int, int]] = {
    "byte": (0, 255), "char": (0, 255),
    "int8": (-(1 << 7), (1 << 7) - 1), "uint8": (0, (1 << 8) - 1),
    "int16": (-(1 << 15), (1 << 15) - 1), "uint16": (0, (1 << 16) - 1),
    "int32": (-(1 << 31), (1 << 31) - 1), "uint32": (0, (1 << 32) - 1),
    "int64": (-(1 << 63), (1 << 63) - 1), "uint64": (0, (1 << 64) - 1),
}

Check = Callable[[Any], Any]


class ValidationError(ValueError):
    """A received value does not conform to its message schema; ``field`` is the dotted path."""

    def __init__(self, type_name: str, field: str, reason: str) -> None:
        super().__init__(f"{type_name}.{field}: {reason}")
        self.type_name = type_name
        self.field = field
        self.reason = reason


class _Bad(Exception):
    """Internal: one value is wrong; the caller adds the field path."""

    def __init__(self, reason: str, sub: str = "") -> None:
        super().__init__(reason)
        self.reason = reason
        self.sub = sub      # path below this field, e.g. "[2]" or ".stamp"


def _describe(v: Any) -> str:
    if type(v) in (int, float, bool):
        return f"{type(v).__name__} {v!r}"
    if type(v) in (str, bytes, list):
        return f"{type(v).__name__} of length {len(v)}"
    return type(v).__name__


def _scalar_check(base: str) -> Check:
    if base == "bool":
        def check_bool(v: Any) -> Any:
            if type(v) is bool:
                return v
            raise _Bad(f"expected bool, got {_describe(v)}")
        return check_bool
    if base in ("float32", "float64"):
        def check_float(v: Any) -> Any:
            if type(v) is float:
                return v
            if type(v) is int:
                try:
                    return float(v)
                except OverflowError:
                    pass
            raise _Bad(f"expected {base}, got {_describe(v)}")
        return check_float
    if base in ("string", "wstring"):
        limit = MAX_STRING_LEN

        def check_str(v: Any) -> Any:
            if type(v) is str and len(v) <= limit:
                return v
            raise _Bad(f"expected {base} of at most {limit} characters, got {_describe(v)}")
        return check_str
    lo, hi = INT_RANGES[base]

    def check_int(v: Any) -> Any:
        if type(v) is int and lo <= v <= hi:
            return v
        raise _Bad(f"expected {base} ({lo}..{hi}), got {_describe(v)}")
    return check_int


def _length_ok(spec: "FieldSpec", n: int, limit: int) -> str | None:
    if spec.array is not None and spec.array >= 0:
        return None if n == spec.array else f"needs exactly {spec.array} elements, got {n}"
    return None if n <= limit else f"at most {limit} elements, got {n}"


def _bytes_check(spec: "FieldSpec") -> Check:
    want = spec.ros_type()

    def check_bytes(v: Any) -> Any:
        if type(v) is bytes:
            why = _length_ok(spec, len(v), MAX_BYTES_LEN)
            if why is None:
                return v
            raise _Bad(f"{want}: {why}")
        if type(v) is list and set(map(type, v)) <= {int} and (not v or (0 <= min(v) and max(v) <= 255)):
            why = _length_ok(spec, len(v), MAX_BYTES_LEN)
            if why is None:
                return bytes(v)
            raise _Bad(f"{want}: {why}")
        raise _Bad(f"expected {want} as bytes, got {_describe(v)}")
    return check_bytes


def _primitive_array_check(spec: "FieldSpec") -> Check:
    base = spec.base
    assert isinstance(base, str)
    want = spec.ros_type()
    element = _scalar_check(base)
    is_float = base in ("float32", "float64")
    ints = INT_RANGES.get(base)

    def check_array(v: Any) -> Any:
        if type(v) is not list:
            raise _Bad(f"expected {want} as a list, got {_describe(v)}")
        why = _length_ok(spec, len(v), MAX_SEQUENCE_LEN)
        if why is not None:
            raise _Bad(f"{want}: {why}")
        # Whole-list checks in C first (set(map(type)), min, max); per element only to name the culprit.
        types = set(map(type, v))
        if is_float:
            if types <= {float}:
                return v
            if types <= {float, int}:
                try:
                    return [float(x) for x in v]
                except OverflowError:
                    pass
        elif ints is not None:
            if types <= {int} and (not v or (ints[0] <= min(v) and max(v) <= ints[1])):
                return v
        elif base == "bool":
            if types <= {bool}:
                return v
        elif types <= {str} and (not v or max(map(len, v)) <= MAX_STRING_LEN):
            return v
        for i, x in enumerate(v):
            try:
                element(x)
            except _Bad as exc:
                raise _Bad(exc.reason, f"[{i}]") from None
        raise _Bad(f"bad {want}")   # unreachable: some element failed above
    return check_array


def _message_check(spec: "FieldSpec") -> Check:
    sub = spec.base
    from_wire: Check = sub._from_wire     # type: ignore[union-attr]
    if spec.array is None:
        def check_message(v: Any) -> Any:
            try:
                return from_wire(v)
            except ValidationError as exc:
                raise _Bad(exc.reason, "." + exc.field) from None
            except (TypeError, ValueError) as exc:
                raise _Bad(str(exc)) from None
        return check_message
    want = spec.ros_type()

    def check_messages(v: Any) -> Any:
        if type(v) is not list:
            raise _Bad(f"expected {want} as a list, got {_describe(v)}")
        why = _length_ok(spec, len(v), MAX_SEQUENCE_LEN)
        if why is not None:
            raise _Bad(f"{want}: {why}")
        out = []
        for i, x in enumerate(v):
            try:
                out.append(from_wire(x))
            except ValidationError as exc:
                raise _Bad(exc.reason, f"[{i}].{exc.field}") from None
            except (TypeError, ValueError) as exc:
                raise _Bad(str(exc), f"[{i}]") from None
        return out
    return check_messages


def field_check(spec: "FieldSpec") -> Check:
    """The checker of one field: returns the (possibly converted) value or raises ``_Bad``."""
    if spec.is_message:
        return _message_check(spec)
    assert isinstance(spec.base, str)
    if spec.is_bytes:
        return _bytes_check(spec)
    if spec.array is not None:
        return _primitive_array_check(spec)
    return _scalar_check(spec.base)


def build_body_check(type_name: str, specs: "tuple[FieldSpec, ...]") -> Callable[[Any], list[Any]]:
    """``check(values) -> list`` of validated field values, or ValidationError."""
    checks = [(s.name, field_check(s)) for s in specs]
    n = len(checks)

    def check_body(values: Any) -> list[Any]:
        if type(values) not in (list, tuple) or len(values) != n:
            raise ValidationError(type_name, "<body>", f"expected {n} field values, got {_describe(values)}")
        out = list(values)
        for i, (name, check) in enumerate(checks):
            try:
                out[i] = check(out[i])
            except _Bad as exc:
                raise ValidationError(type_name, name + exc.sub, exc.reason) from None
        return out
    return check_body
