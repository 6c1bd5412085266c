"""ROS 2 types as zenoh-robot message classes, with their RIHS01 hash and CDR codec (rosbags).

A generated class has ROS 2's type name (``pkg/msg/Type``) and hash (``RIHS01_<sha256>``, which
rosbags computes from the type description as ROS 2 does), so the graph matches endpoints of
the same ROS type and a mismatch of either means no match, as between rmw_zenoh nodes (one
correction: rosidl reads a ``.msg`` ``char`` as ``uint8``, rosbags keeps it a char, so hashes are taken
through :func:`rihs01`, which reads it as ROS 2 does). Its
``_zr_ros2`` attribute is a :class:`Ros2Codec`: the body (``TypeSupport.encode``'s field values)
to the CDR payload rmw_zenoh sends (encapsulation header ``00 01 00 00``, little-endian XCDR1)
and back. The bytes are rosbags' serializer's: a codec generated per type (``fastcdr.py``) makes
them straight from the body where it covers the type, and rosbags (through its objects, which
this module maps our body to) does the rest.

Threading: generating a type takes a lock; codecs are stateless and shared.
"""
from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable
from typing import Any

from ..message import Message, message, type_support
from .fastcdr import FastCodec, build

log = logging.getLogger("zenoh_robot.ros2")
_LOCK = threading.RLock()
_TYPES: dict[str, type[Message]] = {}
_STORE: Any = None
_BYTES = ("uint8", "byte", "char")
_NUMPY = {"bool": "bool", "byte": "uint8", "char": "uint8", "int8": "int8", "uint8": "uint8", "int16": "int16",
          "uint16": "uint16", "int32": "int32", "uint32": "uint32", "int64": "int64", "uint64": "uint64",
          "float32": "float32", "float64": "float64"}
_ZERO = {"bool": False, "string": "", "wstring": "", "float32": 0.0, "float64": 0.0}


def typestore() -> Any:
    """The rosbags typestore the generated types come from (ROS 2 Kilted's standard packages, plus
    whatever :func:`load_ros2_msg` registered)."""
    global _STORE
    with _LOCK:
        if _STORE is None:
            try:
                from rosbags.typesys import Stores, get_typestore
            except ImportError:
                raise ImportError("ROS 2 types need rosbags: pip install 'zenoh-robot[ros2]'") from None
            _STORE = get_typestore(Stores.ROS2_KILTED)
        return _STORE


def _normalise(name: str) -> str:
    parts = name.strip().strip("/").split("/")
    if len(parts) == 2:          # "std_msgs/String": ROS 1 style, still what people type
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"a ROS 2 type name is pkg/msg/Type, got {name!r}")
    return "/".join(parts)


class Ros2Codec:
    """One ROS 2 type's CDR codec over TypeSupport bodies (see the module doc): the generated fast
    path (``fastcdr.py``) where it covers the type, rosbags for the rest and for every body or payload
    the fast path raises on (so errors are rosbags')."""

    def __init__(self, ros_name: str, type_hash: str, to_rosbags: Callable[[Any], Any],
                 from_rosbags: Callable[[Any], list[Any]], fast: FastCodec | None = None) -> None:
        self.ros_name = ros_name
        self.hash = type_hash
        pkg, kind, short = ros_name.split("/")
        self.dds_name = f"{pkg}::{kind}::dds_::{short}_"
        store = typestore()
        self._store = store
        self._to_rosbags = to_rosbags
        self._from_rosbags = from_rosbags
        self.fast = fast
        self._fast_encode = fast.encode if fast is not None else None
        self._fast_decode = fast.decode if fast is not None else None

    def serialize(self, body: Any) -> bytes:
        """The CDR payload of ``body``, its 4-byte encapsulation header included."""
        fast = self._fast_encode
        if fast is not None:
            try:
                return fast(body)
            except Exception:   # noqa: S110 - rosbags either packs it its way or raises its error
                pass
        return self.serialize_rosbags(body)

    def deserialize(self, payload: bytes | memoryview, *, cut_trailing: bool = False) -> list[Any]:
        """The body in ``payload`` (ValueError and friends for bytes that are not this type's CDR).

        ``cut_trailing``: ignore whatever follows the body (PX4's zenoh module sends its uORB struct's
        0-31 bytes of tail padding after a fixed-size body; rosbags, and so the default, accepts at most
        the 3 bytes of CDR alignment)."""
        fast = self._fast_decode
        if fast is not None:
            try:
                return fast(payload, cut_trailing)
            except Exception:   # noqa: S110 - rosbags names what is wrong (or decodes what we did not foresee)
                pass
        return self.deserialize_rosbags(payload, cut_trailing=cut_trailing)

    def serialize_rosbags(self, body: Any) -> bytes:
        """:meth:`serialize` through rosbags alone (the reference)."""
        return bytes(self._store.serialize_cdr(self._to_rosbags(body), self.ros_name))

    def deserialize_rosbags(self, payload: bytes | memoryview, *, cut_trailing: bool = False) -> list[Any]:
        """:meth:`deserialize` through rosbags alone (the reference)."""
        if not cut_trailing:
            return self._from_rosbags(self._store.deserialize_cdr(payload, self.ros_name))
        if len(payload) < 4 or bytes(payload[:2]) not in (b"\x00\x00", b"\x00\x01"):
            raise ValueError("Invalid or unsupported CDR encapsulation.")
        msgdef = self._store.get_msgdef(self.ros_name)
        func = msgdef.deserialize_cdr_le if payload[1] else msgdef.deserialize_cdr_be
        obj, _pos = func(memoryview(payload)[4:], 0, msgdef.cls, self._store)   # no size check: cut
        return self._from_rosbags(obj)


def _field_parts(name: str, desc: tuple[Any, Any]) -> tuple[str, Any, int | None]:
    """(kind, base, array) of a rosbags field: kind 'base' (base: its ROS name) or 'name' (base: a type
    name); array None (scalar), n (fixed) or -1 (sequence)."""
    node, arg = desc
    kind = node.name
    if kind == "BASE":
        return "base", arg[0], None
    if kind == "NAME":
        return "name", arg, None
    (sub_node, sub_arg), size = arg
    if sub_node.name == "BASE":
        return "base", sub_arg[0], size if kind == "ARRAY" else -1
    if sub_node.name == "NAME":
        return "name", sub_arg, size if kind == "ARRAY" else -1
    raise ValueError(f"nested arrays are not supported (field {name!r})")


def _default(kind: str, base: Any, array: int | None, ros: str) -> Any:
    meta = {"ros": ros}
    if array is None:
        if kind == "name":
            return dataclasses.field(default_factory=base, metadata=meta)
        return dataclasses.field(default=_ZERO.get(base, 0), metadata=meta)
    if kind == "base" and base in _BYTES:
        init = bytes(max(array, 0))
        return dataclasses.field(default_factory=lambda: init, metadata=meta)
    if kind == "name":
        return dataclasses.field(default_factory=lambda: [base() for _ in range(max(array, 0))], metadata=meta)
    zero = _ZERO.get(base, 0)
    return dataclasses.field(default_factory=lambda: [zero] * max(array, 0), metadata=meta)


def _converters(kind: str, base: Any, array: int | None) -> tuple[Callable[[Any], Any], Callable[[Any], Any]]:
    """(to rosbags, from rosbags) of one field's value."""
    import numpy as np

    if kind == "name":
        codec: Ros2Codec = base._zr_ros2
        sub_to, sub_from = codec._to_rosbags, codec._from_rosbags
        if array is None:
            return sub_to, sub_from
        return (lambda v: [sub_to(x) for x in v]), (lambda v: [sub_from(x) for x in v])
    if array is None or base in ("string", "wstring"):
        return (lambda v: v if array is None else list(v)), (lambda v: v if array is None else list(v))
    dtype = np.dtype(_NUMPY[base])
    if base in _BYTES:
        return (lambda v: np.frombuffer(bytes(v), dtype=np.uint8)), (lambda v: v.tobytes())
    return (lambda v: np.asarray(v, dtype=dtype)), (lambda v: v.tolist())


def _generate(name: str) -> type[Message]:
    store = typestore()
    if name not in store.fielddefs:
        raise KeyError(f"no ROS 2 definition of {name!r}: load its .msg with zenoh_robot.ros2.load_ros2_msg")
    consts, fields = store.fielddefs[name]
    rb_cls = store.types[name]
    namespace: dict[str, Any] = {"__annotations__": {}, "__module__": "zenoh_robot.ros2." + name.rsplit("/", 1)[0]
                                 .replace("/", ".")}
    to_convs: list[Callable[[Any], Any]] = []
    from_convs: list[Callable[[Any], Any]] = []
    for fname, desc in fields:
        kind, base, array = _field_parts(fname, desc)
        if kind == "name":
            base = ros2_type(base)
            ros = type_support(base).name
        else:
            ros = "string" if base == "wstring" else base
        if array is not None:
            ros += f"[{'' if array < 0 else array}]"
        namespace["__annotations__"][fname] = Any
        namespace[fname] = _default(kind, base, array, ros)
        to_v, from_v = _converters(kind, base, array)
        to_convs.append(to_v)
        from_convs.append(from_v)
    cls = type(name.rsplit("/", 1)[1], (Message,), namespace)
    cls = message(name=name)(cls)
    type_hash = rihs01(name)
    names = [f for f, _ in fields]
    pairs_to = list(zip(to_convs, range(len(names)), strict=True))

    def to_rosbags(body: Any) -> Any:
        return rb_cls(*[conv(body[i]) for conv, i in pairs_to])

    def from_rosbags(obj: Any) -> list[Any]:
        return [conv(getattr(obj, f)) for conv, f in zip(from_convs, names, strict=True)]

    c: Any = cls
    c._type_hash = type_hash
    c._zr_ros2 = Ros2Codec(name, type_hash, to_rosbags, from_rosbags, build(store, name))
    for cname, _ctype, value in consts:
        setattr(cls, cname, value)
    return cls


def ros2_type(name: str) -> type[Message]:
    """The message class of the ROS 2 type ``name`` (``std_msgs/msg/String``; ``std_msgs/String`` too),
    generated once from its definition; KeyError for a type rosbags' store does not know."""
    key = _normalise(name)
    with _LOCK:
        cls = _TYPES.get(key)
        if cls is None:
            if key not in typestore().fielddefs:
                ask_provider(key.split("/", 1)[0])
            cls = _TYPES[key] = _generate(key)
        return cls


_ASKED: set[str] = set()


def ask_provider(package: str) -> None:
    """Let an installed package provide the ROS package ``package``'s definitions (entry-point group
    ``zenoh_robot.ros2_types``, named after the ROS package, a callable that registers them): so the
    tools decode ``px4_msgs`` without importing the drone wing. Asked once per package; a provider
    that fails costs its types, not the caller."""
    if package in _ASKED:
        return
    _ASKED.add(package)
    from importlib.metadata import entry_points

    for ep in entry_points(group="zenoh_robot.ros2_types", name=package):
        try:
            ep.load()()
        except Exception as exc:
            log.warning("ROS 2 types of %s from %s not loaded: %s", package, ep.value, exc)


def load_ros2_msg(text: str, name: str) -> type[Message]:
    """Register the ``.msg`` definition ``text`` as the ROS 2 type ``name`` (``pkg/msg/Type``; service
    halves as ``pkg/srv/Srv_Request``) and return its class. Nested types must be known already."""
    key = name.strip().strip("/")
    with _LOCK:
        register_definitions(parse_definition(text, key))
        return ros2_type(key)


def parse_definition(text: str, name: str) -> dict[str, Any]:
    """rosbags' field definitions of the ``.msg`` text ``text`` of type ``name``, named as ROS 2 names
    them: rosbags files a service half under ``pkg/srv/msg/X`` and a relative nested type of a ``.srv``
    under ``pkg/srv/msg/T``, where ROS 2 (and its hash) says ``pkg/srv/X`` and ``pkg/msg/T``."""
    from rosbags.typesys import get_types_from_msg

    pkg, kind, short = _normalise(name).split("/")
    parsed: dict[str, Any] = get_types_from_msg(text, name)
    if kind == "msg":
        return parsed
    wrong = f"{pkg}/{kind}/msg/"

    def fix(typ: str) -> str:
        if not typ.startswith(wrong):
            return typ
        return f"{pkg}/{kind}/{short}" if typ == wrong + short else f"{pkg}/msg/{typ[len(wrong):]}"

    out: dict[str, Any] = {}
    for typ, (consts, fields) in parsed.items():
        out[fix(typ)] = (consts, [(f, _renamed(desc, fix)) for f, desc in fields])
    return out


def _renamed(desc: tuple[Any, Any], fix: Callable[[str], str]) -> tuple[Any, Any]:
    node, arg = desc
    if node.name == "NAME":
        return node, fix(arg)
    if node.name in ("ARRAY", "SEQUENCE"):
        return node, (_renamed(arg[0], fix), arg[1])
    return desc


def register_definitions(defs: dict[str, Any]) -> None:
    """Add field definitions (``parse_definition``'s) to the typestore; a type generated before from
    an older definition of the same name is made again on next use."""
    with _LOCK:
        typestore().register(defs)
        for key in defs:
            _TYPES.pop(key, None)


def rihs01(name: str) -> str:
    """The RIHS01 hash of a type in the typestore, as ROS 2 computes it. rosbags' ``hash_rihs01``
    describes a ``char`` field as FIELD_TYPE_CHAR, but rosidl maps a ``.msg`` ``char`` to ``uint8``
    (rosidl_adapter), so ROS 2's hash of any type with a char (std_msgs/msg/Char,
    service_msgs/msg/ServiceEventInfo and so every service) describes it as FIELD_TYPE_UINT8: rosbags'
    hashing reads the store through a view that says so."""
    store = typestore()
    return str(type(store).hash_rihs01(_RosidlView(store.fielddefs), name))


class _RosidlView:
    """The typestore's field definitions as rosidl reads them (``char`` as ``uint8``): what rosbags'
    ``hash_rihs01`` needs of its store (only ``fielddefs``)."""

    def __init__(self, fielddefs: dict[str, Any]) -> None:
        self.fielddefs = _CharAsUint8(fielddefs)


class _CharAsUint8(dict[str, Any]):
    def __init__(self, fielddefs: dict[str, Any]) -> None:
        super().__init__()
        self._defs = fielddefs

    def __getitem__(self, typ: str) -> Any:
        consts, fields = self._defs[typ]
        return consts, [(f, _char_as_uint8(desc)) for f, desc in fields]

    def __contains__(self, typ: object) -> bool:
        return typ in self._defs


def _char_as_uint8(desc: tuple[Any, Any]) -> tuple[Any, Any]:
    node, arg = desc
    if node.name == "BASE" and arg[0] == "char":
        return node, ("uint8", arg[1])
    if node.name in ("ARRAY", "SEQUENCE"):
        return node, (_char_as_uint8(arg[0]), arg[1])
    return desc


def is_ros2_type(msg_type: Any) -> bool:
    """Whether ``msg_type`` is a message class with a ROS 2 definition (made here)."""
    return isinstance(msg_type, type) and isinstance(msg_type.__dict__.get("_zr_ros2"), Ros2Codec)


def cdr_codec(msg_type: Any) -> Ros2Codec:
    """The CDR codec of a ROS 2 message class; TypeError naming the type for any other."""
    codec = msg_type.__dict__.get("_zr_ros2") if isinstance(msg_type, type) else None
    if not isinstance(codec, Ros2Codec):
        name = getattr(msg_type, "_type_name", repr(msg_type))
        raise TypeError(f"{name} has no ROS 2 definition: use zenoh_robot.ros2.ros2_type('pkg/msg/Type') "
                        "or load_ros2_msg() on a ROS 2 wire node")
    return codec


def _msg_field_type(desc: tuple[Any, Any]) -> str:
    node, arg = desc
    kind = node.name
    if kind == "BASE":
        return f"{arg[0]}<={arg[1]}" if arg[1] else str(arg[0])
    if kind == "NAME":
        return str(arg).replace("/msg/", "/")     # .msg files name nested types pkg/Type
    (sub, size) = arg
    inner = _msg_field_type(sub)
    if kind == "ARRAY":
        return f"{inner}[{size}]"
    return f"{inner}[<={size}]" if size else f"{inner}[]"


def msg_definition(name: str) -> str:
    """The ``.msg`` text of a known ROS 2 type (constants, then fields; nested types by full name):
    what ``interface show`` prints, and what another implementation can parse into the same hash."""
    key = _normalise(name)
    store = typestore()
    if key not in store.fielddefs:
        raise KeyError(f"no ROS 2 definition of {key!r}")
    consts, fields = store.fielddefs[key]
    lines = [f"{ctype} {cname}={value!r}" if isinstance(value, str) else f"{ctype} {cname}={value}"
             for cname, ctype, value in consts]
    lines += [f"{_msg_field_type(desc)} {fname}" for fname, desc in fields
              if not (fname == "structure_needs_at_least_one_member" and len(fields) == 1)]
    return "\n".join(lines) + ("\n" if lines else "")


def dependencies(name: str) -> list[str]:
    """Every type ``name`` nests, directly or not (depth first, each once)."""
    out: list[str] = []
    store = typestore()

    def walk(t: str) -> None:
        for _f, desc in store.fielddefs[t][1]:
            node, arg = desc
            sub = arg if node.name == "NAME" else (arg[0][1] if node.name in ("ARRAY", "SEQUENCE")
                                                   and arg[0][0].name == "NAME" else None)
            if isinstance(sub, str) and sub not in out:
                out.append(sub)
                walk(sub)
    walk(_normalise(name))
    return out
