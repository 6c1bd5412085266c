"""ROS 2 service types at run time: a ``.srv`` definition -> the request and response message types
(generated as every ROS 2 type here, with their CDR codec), the service's RIHS01 hash and its name.

A service's hash covers the type ROS 2 generates for it (``request_message``, ``response_message``,
``event_message``: ``<Srv>_Event`` holding ``service_msgs/msg/ServiceEventInfo`` and bounded sequences
of one request and one response); the shared hashing (:func:`~zenoh_robot.ros2.types.rihs01`) reads
``ServiceEventInfo.client_gid``'s ``char[16]`` as ROS 2 does, which gives rmw_zenoh's documented
``RIHS01_e118de6b...`` for ``example_interfaces/srv/AddTwoInts``.

Threading: types are made once under the typestore's lock and are immutable after; codecs are
thread safe.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from ..message import Message, type_support
from .types import cdr_codec, parse_definition, register_definitions, rihs01, ros2_type

SERVICE_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"

# Definitions of a few standard services, so `ros2_service_type("std_srvs/srv/SetBool")` needs no file;
# any other service is given its .srv text.
KNOWN_SERVICES: dict[str, str] = {
    "example_interfaces/srv/AddTwoInts": "int64 a\nint64 b\n---\nint64 sum\n",
    "std_srvs/srv/SetBool": "bool data\n---\nbool success\nstring message\n",
    "std_srvs/srv/Trigger": "---\nbool success\nstring message\n",
    "std_srvs/srv/Empty": "---\n",
    # What every action's cancel_goal service is (action_msgs, as ROS 2 Kilted ships it; constants do not
    # enter the hash).
    "action_msgs/srv/CancelGoal": (
        "GoalInfo goal_info\n---\n"
        "int8 ERROR_NONE=0\nint8 ERROR_REJECTED=1\nint8 ERROR_UNKNOWN_GOAL_ID=2\nint8 ERROR_GOAL_TERMINATED=3\n"
        "int8 return_code\nGoalInfo[] goals_canceling\n"),
}


class Ros2TypeError(ValueError):
    """A service type or definition that cannot be used on the ROS 2 wire."""


@dataclass(frozen=True)
class Ros2ServiceType:
    """One ROS 2 service type: its name, hash, and the message types of its two halves."""
    name: str                   # example_interfaces/srv/AddTwoInts
    hash: str                   # RIHS01_<sha256 hex>
    request: type[Message]      # example_interfaces/srv/AddTwoInts_Request
    response: type[Message]

    @property
    def Request(self) -> type[Message]:   # noqa: N802  (rclpy's spelling: ``AddTwoInts.Request(a=1, b=2)``)
        return self.request

    @property
    def Response(self) -> type[Message]:   # noqa: N802
        return self.response

    @property
    def dds_name(self) -> str:
        """The key's type chunk: rmw_zenoh cuts the ``Request_`` suffix of the request's DDS name."""
        pkg, kind, short = self.name.split("/")
        return f"{pkg}::{kind}::dds_::{short}_"

    def encode_request(self, msg: Message) -> bytes:
        return encode_cdr(msg)

    def decode_request(self, data: bytes) -> Message:
        return decode_cdr(self.request, data)

    def encode_response(self, msg: Message) -> bytes:
        return encode_cdr(msg)

    def decode_response(self, data: bytes) -> Message:
        return decode_cdr(self.response, data)


def encode_cdr(msg: Message) -> bytes:
    """The CDR payload (4-byte encapsulation header included) of a ROS 2 message."""
    cls = type(msg)
    return cdr_codec(cls).serialize(type_support(cls).encode(msg))


def decode_cdr(cls: type[Message], data: bytes | memoryview) -> Message:
    """The message of type ``cls`` in a CDR payload, every field validated (ValueError otherwise)."""
    if bytes(data[:2]) != b"\x00\x01":
        raise ValueError(f"not little-endian CDR (encapsulation {bytes(data[:4]).hex() or 'missing'})")
    msg: Message = type_support(cls).decode(cdr_codec(cls).deserialize(data))
    return msg


_lock = threading.Lock()
_types: dict[str, Ros2ServiceType] = {}
_by_message: dict[type, Ros2ServiceType] = {}


def ros2_service_type(name: str, definition: str | None = None) -> Ros2ServiceType:
    """The service type ``name`` (``std_srvs/srv/SetBool``) from its ``.srv`` text (request ``---``
    response), or from :data:`KNOWN_SERVICES`. Made once per name."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] != "srv" or not all(parts):
        raise Ros2TypeError(f"a ROS 2 service type is PKG/srv/NAME, got {name!r}")
    with _lock:
        known = _types.get(name)
        if known is not None:
            return known
        text = definition if definition is not None else KNOWN_SERVICES.get(name)
        if text is None:
            raise Ros2TypeError(f"no definition for service type {name}: give its .srv text "
                                f"(known here: {', '.join(sorted(KNOWN_SERVICES))})")
        halves = ["", text[3:]] if text.startswith("---") else text.split("\n---")
        if len(halves) != 2:
            raise Ros2TypeError(f"{name}: a .srv definition has one '---' line between request and response")
        req_text, resp_text = (h.strip("\n") for h in halves)
        try:
            halves_defs = {**parse_definition(req_text, name + "_Request"),
                           **parse_definition(resp_text, name + "_Response")}
        except Exception as exc:
            raise Ros2TypeError(f"{name}: {exc}") from None
        return _made(name, halves_defs)


def service_from_definitions(name: str, halves: dict[str, Any]) -> Ros2ServiceType:
    """The service type ``name`` (``pkg/srv/S``, or an action's ``pkg/action/A_SendGoal``) from field
    definitions already parsed (``name_Request``, ``name_Response`` and any type they add): what an
    action's derived services are made of. Made once per name."""
    with _lock:
        known = _types.get(name)
        return known if known is not None else _made(name, halves)


def _made(name: str, halves: dict[str, Any]) -> Ros2ServiceType:
    """Register and generate a service type (the caller holds ``_lock``)."""
    try:
        srv_hash = _register(name, halves)
        srv = Ros2ServiceType(name, srv_hash, ros2_type(name + "_Request"), ros2_type(name + "_Response"))
    except Ros2TypeError:
        raise
    except Exception as exc:
        raise Ros2TypeError(f"{name}: {exc}") from None
    _types[name] = srv
    _by_message[srv.request] = srv
    _by_message[srv.response] = srv
    return srv


def service_type_of(request_type: type, response_type: type) -> Ros2ServiceType | None:
    """The ROS 2 service whose halves these message types are (made by :func:`ros2_service_type`)."""
    with _lock:
        srv = _by_message.get(request_type)
    return srv if srv is not None and srv.request is request_type and srv.response is response_type else None


def _register(name: str, halves: dict[str, Any]) -> str:
    """Register the service's four types (halves, event, service) in the typestore; its RIHS01 hash."""
    from rosbags.interfaces import Nodetype

    typs: dict[str, Any] = dict(halves)
    typs[name + "_Event"] = ([], [
        ("info", (Nodetype.NAME, SERVICE_EVENT_INFO)),
        ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, name + "_Request"), 1))),
        ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, name + "_Response"), 1)))])
    typs[name] = ([], [("request_message", (Nodetype.NAME, name + "_Request")),
                       ("response_message", (Nodetype.NAME, name + "_Response")),
                       ("event_message", (Nodetype.NAME, name + "_Event"))])
    register_definitions(typs)
    return rihs01(name)
