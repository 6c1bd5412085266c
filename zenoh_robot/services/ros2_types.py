"""ROS 2 service types at run time: a ``.srv`` definition -> request and response message types, the
service's RIHS01 hash and DDS name, and the CDR codec of both halves (rmw_zenoh's service wire).

Parsing, hashing and CDR come from ``rosbags`` (the ``ros2`` extra), imported on first use so
``import zenoh_robot`` stays light. A service's hash covers the type ROS 2 generates for it
(``request_message``, ``response_message``, ``event_message``: ``<Srv>_Event`` holding
``service_msgs/msg/ServiceEventInfo`` and bounded sequences of one request and one response).
rosbags' store keeps the ``char`` of ``ServiceEventInfo.client_gid`` as a char, while ROS 2 maps
``.msg`` ``char`` to ``uint8``; with rosbags' reading the hash of ``example_interfaces/srv/AddTwoInts``
would not be rmw_zenoh's documented ``RIHS01_e118de6b...``, so the private store here corrects it.

Threading: types are made once under a lock and are immutable after; codecs are thread safe.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..message import Message

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

SERVICE_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"
CDR_HEADER = b"\x00\x01\x00\x00"     # classic CDR, little endian, no options

# Definitions of a few standard services, so `ros2_service_type("std_srvs/srv/SetBool")` needs no file;
# any other service is given its .srv text.
KNOWN_SERVICES: dict[str, str] = {
    "example_interfaces/srv/AddTwoInts": "int64 a\nint64 b\n---\nint64 sum\n",
    "std_srvs/srv/SetBool": "bool data\n---\nbool success\nstring message\n",
    "std_srvs/srv/Trigger": "---\nbool success\nstring message\n",
    "std_srvs/srv/Empty": "---\n",
}


class Ros2TypeError(ValueError):
    """A service type or definition that cannot be used on the ROS 2 wire."""


def dds_service_name(srv_name: str) -> str:
    """``example_interfaces/srv/AddTwoInts`` -> ``example_interfaces::srv::dds_::AddTwoInts_`` (the key's
    type chunk: rmw_zenoh cuts the ``Request_`` suffix of the request's DDS name)."""
    pkg, kind, name = _split(srv_name)
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_service_name(dds_name: str) -> str:
    """``example_interfaces::srv::dds_::AddTwoInts_`` -> ``example_interfaces/srv/AddTwoInts``."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise Ros2TypeError(f"not a DDS type name: {dds_name!r}")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def _split(srv_name: str) -> tuple[str, str, str]:
    parts = srv_name.split("/")
    if len(parts) != 3 or parts[1] != "srv" or not all(parts):
        raise Ros2TypeError(f"a ROS 2 service type is PKG/srv/NAME, got {srv_name!r}")
    return parts[0], parts[1], parts[2]


@dataclass(frozen=True)
class Ros2ServiceType:
    """One ROS 2 service type: its name, hash, and the message types of its two halves."""
    name: str                   # example_interfaces/srv/AddTwoInts
    hash: str                   # RIHS01_<sha256 hex>
    request: type[Message]      # example_interfaces/srv/AddTwoInts_Request
    response: type[Message]

    @property
    def dds_name(self) -> str:
        return dds_service_name(self.name)

    def encode_request(self, msg: Message) -> bytes:
        return _encode(self.name + "_Request", msg)

    def decode_request(self, data: bytes) -> Message:
        return _decode(self.name + "_Request", self.request, data)

    def encode_response(self, msg: Message) -> bytes:
        return _encode(self.name + "_Response", msg)

    def decode_response(self, data: bytes) -> Message:
        return _decode(self.name + "_Response", self.response, data)


_lock = threading.Lock()
_types: dict[str, Ros2ServiceType] = {}
_by_message: dict[type, Ros2ServiceType] = {}
_store: Typestore | None = None


def ros2_service_type(name: str, definition: str | None = None) -> Ros2ServiceType:
    """The service type ``name`` (``std_srvs/srv/SetBool``) from its ``.srv`` text (request ``---``
    response), or from :data:`KNOWN_SERVICES`. Made once per name; a second definition of a known
    name must be the same text."""
    pkg, _kind, short = _split(name)
    with _lock:
        known = _types.get(name)
        if known is not None:
            return known
        text = definition if definition is not None else KNOWN_SERVICES.get(name)
        if text is None:
            raise Ros2TypeError(f"no definition for service type {name}: give its .srv text "
                                f"(known here: {', '.join(sorted(KNOWN_SERVICES))})")
        halves = text.split("\n---")
        if text.startswith("---"):
            halves = ["", text[3:]]
        if len(halves) != 2:
            raise Ros2TypeError(f"{name}: a .srv definition has one '---' line between request and response")
        req_text, resp_text = (h.strip("\n") for h in halves)
        srv_hash = _register(name, req_text, resp_text)
        request = _message_class(pkg, short + "_Request", req_text)
        response = _message_class(pkg, short + "_Response", resp_text)
        srv = Ros2ServiceType(name, srv_hash, request, response)
        _types[name] = srv
        _by_message[request] = srv
        _by_message[response] = srv
        return srv


def service_type_of(request_type: type, response_type: type) -> Ros2ServiceType | None:
    """The ROS 2 service whose halves these message types are (made by :func:`ros2_service_type`)."""
    with _lock:
        srv = _by_message.get(request_type)
    return srv if srv is not None and srv.request is request_type and srv.response is response_type else None


def _message_class(pkg: str, name: str, text: str) -> type[Message]:
    from ..msg_loader import MsgParseError, load_msg

    try:
        return load_msg(text, name=name, package=f"{pkg}/srv")
    except MsgParseError as exc:
        raise Ros2TypeError(str(exc)) from None


def _typestore() -> Typestore:
    global _store
    if _store is None:
        try:
            from rosbags.interfaces import Nodetype
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise Ros2TypeError("ROS 2 service types need rosbags: pip install 'zenoh-robot[ros2]'") from None
        store = get_typestore(Stores.ROS2_JAZZY)     # our own instance: the fix below stays here
        defs: Any = store.fielddefs
        consts, fields = defs[SERVICE_EVENT_INFO]
        uint8_16 = (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), 16))
        defs[SERVICE_EVENT_INFO] = (consts, [(n, uint8_16 if n == "client_gid" else d) for n, d in fields])
        _store = store
    return _store


def _register(name: str, req_text: str, resp_text: str) -> str:
    """Register the service's four types in the private store; its RIHS01 hash."""
    from rosbags.interfaces import Nodetype
    from rosbags.typesys import get_types_from_msg

    store = _typestore()
    typs: dict[str, Any] = {}
    for suffix, text in (("_Request", req_text), ("_Response", resp_text)):
        try:
            parsed = get_types_from_msg(text, name + suffix)
        except Exception as exc:
            raise Ros2TypeError(f"{name}{suffix}: {exc}") from None
        # rosbags names a srv half PKG/srv/msg/X; ROS 2 (and its hash) says PKG/srv/X.
        for key, value in parsed.items():
            typs[name + suffix if key.endswith("/" + name.rsplit("/", 1)[1] + suffix) else key] = value
    typs[name + "_Event"] = ([], [
        ("info", (Nodetype.NAME, SERVICE_EVENT_INFO)),
        ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, name + "_Request"), 1))),
        ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, name + "_Response"), 1)))])
    typs[name] = ([], [("request_message", (Nodetype.NAME, name + "_Request")),
                       ("response_message", (Nodetype.NAME, name + "_Response")),
                       ("event_message", (Nodetype.NAME, name + "_Event"))])
    try:
        store.register(typs)
    except Exception as exc:
        raise Ros2TypeError(f"{name}: {exc}") from None
    return str(store.hash_rihs01(name))


# -- CDR: message -> rosbags object -> bytes, and back ------------------------------------------
def _encode(typename: str, msg: Message) -> bytes:
    store = _typestore()
    obj = _to_ros(store, typename, msg.to_dict())
    return bytes(store.serialize_cdr(obj, typename))


def _decode(typename: str, cls: type[Message], data: bytes) -> Message:
    from ..message import validated

    if data[:2] != CDR_HEADER[:2]:
        raise ValueError(f"not little-endian CDR (encapsulation {data[:4].hex() or 'missing'})")
    store = _typestore()
    obj = store.deserialize_cdr(data, typename)
    fields = _from_ros(obj)
    fields.pop("structure_needs_at_least_one_member", None)
    msg: Message = validated(cls.from_dict(fields))
    return msg


def _to_ros(store: Typestore, typename: str, data: dict[str, Any]) -> Any:
    import numpy as np
    from rosbags.interfaces import Nodetype

    defs: Any = store.fielddefs
    _consts, fields = defs[typename]
    kwargs: dict[str, Any] = {}
    for fname, (node, rest) in fields:
        value = data.get(fname)
        if node == Nodetype.NAME:
            kwargs[fname] = _to_ros(store, rest, value or {})
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (sub_node, sub), _size = rest
            items = list(value or [])
            if sub_node == Nodetype.NAME:
                kwargs[fname] = [_to_ros(store, sub, v) for v in items]
            elif sub[0] in ("string", "wstring"):
                kwargs[fname] = [str(v) for v in items]
            else:
                kwargs[fname] = np.array(items, dtype=_NUMPY[sub[0]])
        elif value is None:     # rosbags' filler of an empty struct (structure_needs_at_least_one_member)
            kwargs[fname] = "" if rest[0] in ("string", "wstring") else 0
        else:
            kwargs[fname] = value
    return store.types[typename](**kwargs)


def _from_ros(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (list, tuple)):
        return [_from_ros(v) for v in obj]
    names = getattr(obj, "__dataclass_fields__", None)
    if names is not None:
        return {n: _from_ros(getattr(obj, n)) for n in names if n != "__msgtype__"}
    return obj


_NUMPY = {"bool": "bool", "byte": "uint8", "char": "uint8", "uint8": "uint8", "int8": "int8", "uint16": "uint16",
          "int16": "int16", "uint32": "uint32", "int32": "int32", "uint64": "uint64", "int64": "int64",
          "float32": "float32", "float64": "float64", "octet": "uint8"}
