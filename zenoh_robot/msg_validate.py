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

Two implementations of these rules, one behaviour. :func:`build_body_check` is the
reference: a checker closure per field, interpreted per sample (clear, but 2-10 us a
message). :func:`build_decoder` generates, once per type, Python source for that type's
fields (nested messages inlined, literal ranges, fixed lengths unrolled) and ``compile()``s
it: the common case, a conforming body, costs little more than building the message.
Anything the generated fast path does not accept as is (a wrong type, a tuple body, an
int list for bytes, an overflow) falls back to the reference, which converts or raises:
so errors carry exactly the reference's messages and field paths, and the fast path only
has to be *at most* as permissive as the reference (tests/library/test_validate_codegen.py
checks both on many generated shapes).
"""
from __future__ import annotations

import linecache
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .message import FieldSpec

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


def _message_check(spec: "FieldSpec", reference: bool = False) -> Check:
    sub = spec.base
    # The reference checks nested types with their reference too (so a test compares two whole
    # implementations); production nests the sub-type's generated decoder.
    nested = getattr(sub, "_zr_reference_from_wire", None) if reference else None
    from_wire: Check = nested or sub._from_wire     # type: ignore[union-attr]
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


def field_check(spec: "FieldSpec", reference: bool = False) -> Check:
    """The checker of one field: returns the (possibly converted) value or raises ``_Bad``."""
    if spec.is_message:
        return _message_check(spec, reference)
    assert isinstance(spec.base, str)
    if spec.is_bytes:
        return _bytes_check(spec)
    if spec.array is not None:
        return _primitive_array_check(spec)
    return _scalar_check(spec.base)


def build_body_check(type_name: str, specs: "tuple[FieldSpec, ...]",
                     reference: bool = False) -> Callable[[Any], list[Any]]:
    """``check(values) -> list`` of validated field values, or ValidationError (the reference rules)."""
    checks = [(s.name, field_check(s, reference)) for s in specs]
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


# -- generated decoders --------------------------------------------------------------------------
# Fixed float arrays up to this length are checked element by element in the generated source
# (three `type(x) is float` tests beat building a set of types); longer ones by set in C.
_UNROLL = 8
# Nested messages are inlined this deep; deeper ones call their own type's generated fast path.
_INLINE_DEPTH = 4


class _Fallback(Exception):
    """Internal: the fast path does not take this body as is; the reference decides."""


# Raised as the class, so each fall-back is a new instance. One shared instance leaked: every
# `raise` prepends the raising frames to the instance's __traceback__, so the chain kept every
# refused body (and its caller frames: the whole payload) alive, ~2.8 kB a sample without bound
# (issue #24: +590 MB after a fuzz storm).
_FALL = _Fallback


def _floats(v: list[Any]) -> list[float] | None:
    """A float list with ints converted (as the reference does), or None if anything else is in it."""
    if _FLOAT_OR_INT.issuperset(map(type, v)):
        return [float(x) for x in v]     # OverflowError: the reference names the element
    return None


_FLOAT_ONLY = frozenset({float})
_FLOAT_OR_INT = frozenset({float, int})
_INT_ONLY = frozenset({int})
_BOOL_ONLY = frozenset({bool})
_STR_ONLY = frozenset({str})


class _Source:
    """Python source of one type's decoder, and the names it refers to."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.ns: dict[str, Any] = {
            "_V": sys.modules[__name__], "_FALL": _FALL, "_floats": _floats, "_FLOAT_ONLY": _FLOAT_ONLY,
            "_INT_ONLY": _INT_ONLY, "_BOOL_ONLY": _BOOL_ONLY, "_STR_ONLY": _STR_ONLY,
        }
        self._consts: dict[int, str] = {}

    def const(self, obj: Any, prefix: str) -> str:
        name = self._consts.get(id(obj))
        if name is None:
            name = self._consts[id(obj)] = f"_{prefix}{len(self._consts)}"
            self.ns[name] = obj
        return name

    def add(self, indent: int, line: str) -> None:
        self.lines.append("    " * indent + line)


def _emit_scalar(src: _Source, base: str, v: str, ind: int) -> None:
    if base == "bool":
        src.add(ind, f"if type({v}) is not bool: raise _FALL")
    elif base in ("float32", "float64"):
        src.add(ind, f"if type({v}) is not float:")
        src.add(ind + 1, f"if type({v}) is not int: raise _FALL")
        src.add(ind + 1, f"{v} = float({v})")
    elif base in ("string", "wstring"):
        # The reference captures the string limit when it is built: so does this.
        src.add(ind, f"if type({v}) is not str or len({v}) > {MAX_STRING_LEN}: raise _FALL")
    else:
        lo, hi = INT_RANGES[base]
        src.add(ind, f"if type({v}) is not int or {v} < {lo} or {v} > {hi}: raise _FALL")


def _emit_length(src: _Source, spec: "FieldSpec", v: str, ind: int, limit: str) -> None:
    assert spec.array is not None
    bad_len = f"len({v}) != {spec.array}" if spec.array >= 0 else f"len({v}) > _V.{limit}"
    src.add(ind, f"if type({v}) is not list or {bad_len}: raise _FALL")


def _emit_primitive_array(src: _Source, spec: "FieldSpec", v: str, ind: int) -> None:
    base = spec.base
    assert isinstance(base, str) and spec.array is not None
    _emit_length(src, spec, v, ind, "MAX_SEQUENCE_LEN")
    if base in ("float32", "float64"):
        if 0 <= spec.array <= _UNROLL:
            if spec.array:
                test = " or ".join(f"type({v}[{i}]) is not float" for i in range(spec.array))
                src.add(ind, f"if {test}:")
                src.add(ind + 1, f"{v} = _floats({v})")
                src.add(ind + 1, f"if {v} is None: raise _FALL")
        else:
            src.add(ind, f"if not _FLOAT_ONLY.issuperset(map(type, {v})):")
            src.add(ind + 1, f"{v} = _floats({v})")
            src.add(ind + 1, f"if {v} is None: raise _FALL")
    elif base == "bool":
        src.add(ind, f"if not _BOOL_ONLY.issuperset(map(type, {v})): raise _FALL")
    elif base in ("string", "wstring"):
        src.add(ind, f"if {v} and (not _STR_ONLY.issuperset(map(type, {v})) "
                     f"or max(map(len, {v})) > _V.MAX_STRING_LEN): raise _FALL")
    else:
        lo, hi = INT_RANGES[base]
        src.add(ind, f"if {v} and (not _INT_ONLY.issuperset(map(type, {v})) "
                     f"or min({v}) < {lo} or max({v}) > {hi}): raise _FALL")


def _emit_message(src: _Source, cls: type, v: str, ind: int, depth: int) -> None:
    """Lines leaving in ``v`` the ``cls`` built from the body in ``v``, or raising _FALL."""
    specs: tuple[FieldSpec, ...] = cls._fields_spec      # type: ignore[attr-defined]
    src.add(ind, f"if type({v}) is not list or len({v}) != {len(specs)}: raise _FALL")
    names = [f"{v}_{i}" for i in range(len(specs))]
    if names:
        src.add(ind, f"{', '.join(names)}, = {v}")
    for spec, name in zip(specs, names, strict=True):
        _emit_field(src, spec, name, ind, depth)
    src.add(ind, f"{v} = {src.const(cls, 'C')}({', '.join(names)})")


def _emit_field(src: _Source, spec: "FieldSpec", v: str, ind: int, depth: int) -> None:
    if spec.is_message:
        sub = spec.base
        assert isinstance(sub, type)
        if spec.array is None:
            if depth < _INLINE_DEPTH:
                _emit_message(src, sub, v, ind, depth + 1)
            else:
                src.add(ind, f"{v} = {src.const(sub._zr_try_from_wire, 'T')}({v})")
                src.add(ind, f"if {v} is None: raise _FALL")
            return
        _emit_length(src, spec, v, ind, "MAX_SEQUENCE_LEN")
        try_sub = src.const(sub._zr_try_from_wire, "T")
        src.add(ind, f"{v} = [{try_sub}(x) for x in {v}]")
        src.add(ind, f"if None in {v}: raise _FALL")
        return
    assert isinstance(spec.base, str)
    if spec.is_bytes:
        bad_len = (f"len({v}) != {spec.array}" if spec.array is not None and spec.array >= 0
                   else f"len({v}) > _V.MAX_BYTES_LEN")
        src.add(ind, f"if type({v}) is not bytes or {bad_len}: raise _FALL")
    elif spec.array is not None:
        _emit_primitive_array(src, spec, v, ind)
    else:
        _emit_scalar(src, spec.base, v, ind)


def decoder_source(cls: type) -> tuple[str, dict[str, Any]]:
    """The generated source of ``cls``'s fast paths and the namespace it runs in (for tests, debugging)."""
    body = _Source()
    _emit_message(body, cls, "values", 2, 0)
    body.add(2, "return values")
    src = _Source()
    src.ns.update(body.ns)
    src.ns["_slow"] = cls._zr_reference_decode      # type: ignore[attr-defined]
    # The body twice rather than one shared function: a Python call is a tenth of a small decode.
    src.add(0, "def try_from_wire(values):")
    src.add(1, "try:")
    src.lines += body.lines
    src.add(1, "except Exception:")
    src.add(2, "return None")
    src.add(0, "")
    src.add(0, "def from_wire(values):")
    src.add(1, "try:")
    src.lines += body.lines
    src.add(1, "except Exception:")
    src.add(2, "pass")
    src.add(1, "return _slow(values)   # converts or raises exactly as the reference does")
    return "\n".join(src.lines) + "\n", src.ns


def build_decoder(cls: type) -> tuple[Callable[[Any], Any], Callable[[Any], Any]]:
    """``(from_wire, try_from_wire)`` generated for ``cls``; needs ``cls._zr_reference_decode`` set.

    ``try_from_wire`` returns None for any body the fast path does not take (for arrays of
    this type inside another); ``from_wire`` then asks the reference, which converts or raises.
    """
    text, ns = decoder_source(cls)
    filename = f"<zenoh_robot decoder {cls._type_name}>"      # type: ignore[attr-defined]
    # Tracebacks and profilers show the generated lines.
    linecache.cache[filename] = (len(text), None, text.splitlines(True), filename)
    exec(compile(text, filename, "exec"), ns)
    return ns["from_wire"], ns["try_from_wire"]
