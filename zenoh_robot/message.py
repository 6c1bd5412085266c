"""Typed message base: field specs, type hash and the wire form of a message.

A message type is a dataclass decorated with :func:`message`. Its fields are
described by ROS-style type strings (``float64``, ``float64[3]``, ``string``,
``uint8[]``, a nested message type), inferred from the annotations or given
explicitly with :func:`array` / :func:`ros_field`. The wire form is a msgpack
array of field values in declaration order: compact, and fast to build with
``operator.attrgetter``. The type hash covers names and types, so a reader with
a different field order or layout sees a mismatch instead of garbage.
"""
from __future__ import annotations

import dataclasses
import hashlib
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from operator import attrgetter
from typing import Any, ClassVar

from .msg_validate import ValidationError, build_body_check, build_decoder  # noqa: F401  (ValidationError: re-exported)

PRIMITIVES: dict[str, type] = {
    "bool": bool,
    "byte": int, "char": int,
    "int8": int, "uint8": int, "int16": int, "uint16": int,
    "int32": int, "uint32": int, "int64": int, "uint64": int,
    "float32": float, "float64": float,
    "string": str, "wstring": str,
}
_DEFAULTS = {bool: False, int: 0, float: 0.0, str: ""}


@dataclass(frozen=True, slots=True)
class FieldSpec:
    """One field: ROS base type (primitive name or message class) and array size.

    ``array`` is None for a scalar, -1 for an unbounded array and n >= 0 for a
    fixed array of n elements. ``uint8``/``byte`` arrays travel as bytes.
    """
    name: str
    base: str | type["Message"]
    array: int | None = None

    @property
    def is_message(self) -> bool:
        return not isinstance(self.base, str)

    @property
    def is_bytes(self) -> bool:
        return self.array is not None and self.base in ("uint8", "byte", "char")

    def ros_type(self) -> str:
        base = self.base if isinstance(self.base, str) else self.base._type_name
        if self.array is None:
            return base
        return f"{base}[{'' if self.array < 0 else self.array}]"


def parse_type(text: str, resolve: Callable[[str], type] | None = None) -> tuple[str | type, int | None]:
    """Split ``float64[3]`` into ("float64", 3); ``x[]`` -> -1; nested names via ``resolve``."""
    text = text.strip()
    array: int | None = None
    if text.endswith("]"):
        base, _, size = text[:-1].partition("[")
        size = size.strip()
        if size.startswith("<="):  # bounded array: treat as unbounded with a cap ignored
            size = ""
        try:
            array = int(size) if size else -1
        except ValueError:
            raise ValueError(f"bad array size in type {text!r}") from None
        if array < -1:
            raise ValueError(f"negative array size in type {text!r}")
        text = base.strip()
    if text.startswith("string<="):
        text = "string"
    if text in PRIMITIVES:
        return text, array
    if resolve is None:
        raise ValueError(f"unknown field type {text!r}")
    return resolve(text), array


def array(base: str, size: int = -1, default: Any = None) -> Any:
    """A dataclass field for a ROS array, e.g. ``gyro: list[float] = array("float64", 3)``."""
    ros = f"{base}[{'' if size < 0 else size}]"
    if default is None:
        if base in ("uint8", "byte", "char"):
            default_factory: Callable[[], Any] = (lambda: bytes(max(size, 0)))
        else:
            zero = _DEFAULTS.get(PRIMITIVES.get(base, float), 0.0)
            default_factory = (lambda: [zero] * max(size, 0))
    else:
        default_factory = (lambda: list(default))
    return field(default_factory=default_factory, metadata={"ros": ros})


def ros_field(ros_type: str, default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field with an explicit ROS type, e.g. ``ros_field("float32", 0.0)``."""
    return field(default=default, metadata={"ros": ros_type})


class Message:
    """Base of every message type. Use the :func:`message` decorator, not this directly."""
    __slots__ = ()
    _type_name: ClassVar[str]
    _type_hash: ClassVar[str]
    _fields_spec: ClassVar[tuple[FieldSpec, ...]]
    _to_wire: ClassVar[Callable[[Any], Any]]
    _from_wire: ClassVar[Callable[[Any], Any]]
    # Set by @message (see zenoh_robot/msg_validate.py): the generated fast path and the reference rules.
    _zr_try_from_wire: ClassVar[Callable[[Any], Any]]
    _zr_reference_decode: ClassVar[Callable[[Any], Any]]
    _zr_reference_from_wire: ClassVar[Callable[[Any], Any]]
    # True on message types that topic statistics never watch (the statistics themselves).
    __zr_no_statistics__: ClassVar[bool] = False

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for spec in self._fields_spec:
            value = getattr(self, spec.name)
            if spec.is_message:
                value = [v.to_dict() for v in value] if spec.array is not None else value.to_dict()
            out[spec.name] = value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Message":
        """Build from a (possibly partial) dict, e.g. parsed YAML; unknown keys are an error."""
        if not isinstance(data, dict):
            raise ValueError(f"{cls._type_name}: expected a mapping, got {type(data).__name__}")
        names = {s.name: s for s in cls._fields_spec}
        unknown = set(data) - set(names)
        if unknown:
            raise ValueError(f"{cls._type_name} has no field(s) {sorted(unknown)}; fields: {sorted(names)}")
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            spec = names[key]
            sub = spec.base
            if not isinstance(sub, str):   # a nested message type
                value = [sub.from_dict(v) for v in value] if spec.array is not None else sub.from_dict(value)
            kwargs[key] = value
        return cls(**kwargs)


def _infer(name: str, annotation: Any) -> tuple[str | type, int | None]:
    if isinstance(annotation, str):
        raise TypeError(f"field {name!r}: string annotation; use ros_field() or resolve it")
    if annotation in (float,):
        return "float64", None
    if annotation is int:
        return "int64", None
    if annotation is bool:
        return "bool", None
    if annotation is str:
        return "string", None
    if annotation in (bytes, bytearray):
        return "uint8", -1
    if isinstance(annotation, type) and issubclass(annotation, Message):
        return annotation, None
    origin = typing.get_origin(annotation)
    if origin is list:
        (inner,) = typing.get_args(annotation) or (float,)
        base, sub = _infer(name, inner)
        if sub is not None:
            raise TypeError(f"field {name!r}: nested arrays are not supported")
        return base, -1
    raise TypeError(f"field {name!r}: cannot map annotation {annotation!r} to a ROS type; use ros_field()")


def _spec_of(cls: type) -> tuple[FieldSpec, ...]:
    hints = typing.get_type_hints(cls)
    specs = []
    for f in dataclasses.fields(cls):
        ros = f.metadata.get("ros")
        if ros is not None:
            base, arr = parse_type(ros, resolve=lookup)
        else:
            base, arr = _infer(f.name, hints[f.name])
        specs.append(FieldSpec(f.name, base, arr))
    return tuple(specs)


def compute_hash(type_name: str, specs: tuple[FieldSpec, ...]) -> str:
    """Stable hash of names and types; nested types contribute their own hash."""
    h = hashlib.sha256(type_name.encode())
    for s in specs:
        base = s.base if isinstance(s.base, str) else s.base._type_hash
        h.update(f"\n{s.name}:{base}:{s.array}".encode())
    return h.hexdigest()[:16]


def _check_fixed(type_name: str, spec: FieldSpec, value: Any) -> None:
    if len(value) != spec.array:
        raise ValueError(
            f"{type_name}.{spec.name}: fixed array {spec.ros_type()} needs {spec.array} elements, got {len(value)}")


def _build_codec(cls: type["Message"]) -> tuple[Callable[[Any], Any], Callable[[Any], Any]]:
    specs = cls._fields_spec
    names = [s.name for s in specs]
    simple = all(not s.is_message and (s.array is None or s.array < 0) for s in specs)
    getter: Callable[[Any], tuple[Any, ...]]
    if len(names) > 1:
        getter = attrgetter(*names)
    elif names:
        first = names[0]
        getter = lambda m: (getattr(m, first),)  # noqa: E731
    else:
        getter = lambda m: ()  # noqa: E731
    type_name = cls._type_name
    to_wire: Callable[[Any], Any]
    if simple:
        to_wire = getter
    else:
        def to_wire(msg: Any) -> list[Any]:
            out = list(getter(msg))
            for i, spec in enumerate(specs):
                v = out[i]
                if spec.array is not None and spec.array >= 0:
                    _check_fixed(type_name, spec, v)
                sub = spec.base
                if not isinstance(sub, str):   # a nested message type
                    if spec.array is None:
                        out[i] = sub._to_wire(v)
                    else:
                        out[i] = [sub._to_wire(x) for x in v]
            return out

    # Every field is checked against the schema (types, ranges, lengths, nested types): a body from
    # the network must not hand a callback a str where it expects a float (see zenoh_robot/msg_validate.py).
    # The reference checker decides every body the generated fast path does not take as is.
    check_body = build_body_check(type_name, specs)
    reference_check = build_body_check(type_name, specs, reference=True)

    def reference_decode(values: Any) -> Any:
        return cls(*check_body(values))

    def reference_from_wire(values: Any) -> Any:    # all-reference, nested types too: for tests
        return cls(*reference_check(values))

    c: Any = cls
    c._zr_reference_decode = reference_decode
    c._zr_reference_from_wire = reference_from_wire
    from_wire, c._zr_try_from_wire = build_decoder(cls)
    return to_wire, from_wire


_T = typing.TypeVar("_T", bound=type)


@typing.overload
def message(cls: _T, *, name: str | None = None) -> _T: ...


@typing.overload
def message(cls: None = None, *, name: str | None = None) -> Callable[[_T], _T]: ...


# dataclass_transform: type checkers see an @message class as the dataclass it becomes.
@typing.dataclass_transform(field_specifiers=(field, array, ros_field))
def message(cls: type | None = None, *, name: str | None = None) -> Any:
    """Class decorator: make ``cls`` a dataclass message type with a type name and hash."""
    def wrap(c: type) -> type:
        if not issubclass(c, Message):
            raise TypeError(f"@message class {c.__name__} must derive from zenoh_robot.Message")
        c = dataclass(slots=True)(c)
        c._type_name = name or f"{c.__module__.split('.')[0]}/{c.__name__}"
        c._fields_spec = _spec_of(c)
        c._type_hash = compute_hash(c._type_name, c._fields_spec)
        c._to_wire, c._from_wire = _build_codec(c)
        register(c)
        return c
    return wrap(cls) if cls is not None else wrap


_REGISTRY: dict[str, type[Message]] = {}


def register(cls: type["Message"]) -> None:
    """Make a type findable by name (for the CLI and the .msg loader's nested types)."""
    _REGISTRY[cls._type_name] = cls
    _REGISTRY.setdefault(cls.__name__, cls)


def lookup(type_name: str) -> type[Message]:
    """Find a message type by full (``zenoh_robot/Setpoint``) or short (``Setpoint``) name."""
    try:
        return _REGISTRY[type_name]
    except KeyError:
        short = type_name.rsplit("/", 1)[-1]
        if short in _REGISTRY:
            return _REGISTRY[short]
        known = sorted(k for k in _REGISTRY if "/" not in k)
        raise KeyError(f"unknown message type {type_name!r}; known: {', '.join(known)}") from None


@dataclass(frozen=True, slots=True)
class TypeSupport:
    """What the wire needs of a message type: its name and hash, and its body codec.

    The one way code outside this module reaches a type's wire form (rclpy's type support).
    """
    name: str
    hash: str
    encode: Callable[[Any], Any]     # message -> msgpack-ready body
    decode: Callable[[Any], Any]     # body -> message; ValueError/TypeError for a body that does not fit
    msg_type: type


def type_support(msg_type: Any) -> TypeSupport:
    """The :class:`TypeSupport` of an @message class; TypeError for anything else."""
    if not (isinstance(msg_type, type) and issubclass(msg_type, Message) and hasattr(msg_type, "_type_hash")):
        raise TypeError(f"{msg_type!r} is not a message type (an @message class)")
    cached = msg_type.__dict__.get("_zr_type_support")
    if cached is None:
        cached = TypeSupport(msg_type._type_name, msg_type._type_hash, msg_type._to_wire, msg_type._from_wire,
                             msg_type)
        type.__setattr__(msg_type, "_zr_type_support", cached)
    return cached


def require_message_type(t: Any, context: str) -> None:
    """A clear TypeError when ``t`` is not a message type (``context`` says where it was given)."""
    if not (isinstance(t, type) and issubclass(t, Message)):
        raise TypeError(f"{context}: {t!r} is not a message type (an @message class)")


def validated(msg: Any) -> Any:
    """A copy of ``msg`` whose every field passed the wire checks (ValidationError otherwise).

    For messages built from a mapping (``from_dict``, a service's dict form), which bypass
    ``_from_wire``: the same rules then hold whichever way a request arrived.
    """
    cls = type(msg)
    return cls._from_wire(list(cls._to_wire(msg)))
