"""Play a bag's ROS 2 channels (``cdr`` messages, ``ros2msg`` schema) on the ROS 2 wire (``bag play``).

Each channel becomes one ROS 2 publisher of the player's node, as rmw_zenoh makes one: the data key
``<domain>/<topic>/<pkg>::msg::dds_::<Type>_/<RIHS01 hash>``, an ``MP`` liveliness token, and on every
put the 33-byte attachment (sequence, source stamp, GID); the payload is the recorded CDR, untouched.

- Type: the schema's name (``pkg/msg/Type``, or rosbag2's older ``pkg/Type``). Hash: the one the recorded
  publisher announced (``zr.hash``, written by ``bag record``), else computed from the schema text (a
  rosbag2 file). The schema's definitions are parsed through ``zenoh_robot.ros2`` and registered where
  this process does not know a type; a type it knows with another definition is never replaced, so
  such a channel plays only with its recorded hash.
- QoS: the recorded publisher's (``zr.qos``), else rosbag2's ``offered_qos_profiles`` (reliable and
  transient local only when every recorded publisher was), else ROS 2's default (reliable, volatile,
  keep last 10).
- Sequence numbers count from 1 per channel and go on across ``--loop`` passes, so subscriptions take
  every pass as new samples.

:func:`describe` raises :class:`Unplayable`, one line saying why, for a channel it cannot play.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from zenoh_robot.graph import NodeInfo, decode_qos
from zenoh_robot.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from zenoh_robot.qos_mapping import declare_publisher
from zenoh_robot.wire import Ros2WireFormat
from zenoh_robot.wire.ros2 import PUBLISHER, Ros2Graph, dds_type_name, pack_attachment, token_gid

from .encodings import ROS2MSG

if TYPE_CHECKING:
    from mcap.records import Channel, Schema

    from zenoh_robot.node import Node


class Unplayable(Exception):
    """Why a channel cannot be played, in one line."""


@dataclass(frozen=True)
class Ros2Channel:
    """What a bag's ROS 2 channel is played as."""
    topic: str
    type_name: str
    type_hash: str
    qos: QoSProfile
    codec: Any          # the type's zenoh_robot.ros2.Ros2Codec, None when this process has another definition


def type_name_of(schema_name: str) -> str:
    """``pkg/msg/Type`` of a schema name (rosbag2 writes ``pkg/msg/Type``, older files ``pkg/Type``)."""
    parts = schema_name.strip().strip("/").split("/")
    if len(parts) == 2:
        parts.insert(1, "msg")
    if len(parts) != 3 or parts[1] != "msg" or not all(p.isidentifier() for p in parts):
        raise Unplayable(f"schema name {schema_name!r} is not a ROS 2 message type (pkg/msg/Type)")
    return "/".join(parts)


def describe(channel: "Channel", schema: "Schema | None") -> Ros2Channel:
    """The ROS 2 publisher a ``cdr`` channel plays as; :class:`Unplayable` for one it cannot."""
    if schema is None or not schema.data:
        raise Unplayable("no schema: the type is unknown")
    if schema.encoding != ROS2MSG:
        raise Unplayable(f"schema encoding {schema.encoding!r}: only ros2msg definitions are played")
    name = type_name_of(schema.name)
    try:
        text = bytes(schema.data).decode("utf-8")
    except UnicodeDecodeError:
        raise Unplayable("its ros2msg schema is not UTF-8 text") from None
    recorded = channel.metadata.get("zr.hash", "")
    type_hash, codec = _resolve(name, text, recorded)
    return Ros2Channel("/" + channel.topic.strip("/"), name, type_hash, channel_qos(channel.metadata), codec)


def _resolve(name: str, text: str, recorded: str) -> tuple[str, Any]:
    """(type hash, codec or None): see the module doc."""
    try:
        from zenoh_robot.ros2 import cdr_codec, rihs01, ros2_type, typestore
        from zenoh_robot.ros2.types import parse_definition, register_definitions

        store = typestore()
    except ImportError:
        raise Unplayable("ROS 2 channels need rosbags: pip install 'zenoh-robot[ros2]'") from None
    with contextlib.suppress(KeyError, ValueError):
        ros2_type(name)         # lets an installed provider (px4_msgs) register its package first
    try:
        defs = parse_definition(text, name)
    except Exception as exc:    # rosbags' parser raises its own kinds
        raise Unplayable(f"its ros2msg schema does not parse: {_one_line(exc)}") from None
    if name not in defs:
        raise Unplayable(f"its ros2msg schema does not define {name}")
    differs = sorted(t for t, (_consts, fields) in defs.items()
                     if t in store.fielddefs and store.fielddefs[t][1] != fields)
    try:
        register_definitions({t: d for t, d in defs.items() if t not in store.fielddefs})
        if differs:
            if not recorded:
                raise Unplayable(f"{differs[0]} in the bag differs from this process's definition and the bag "
                                 "names no type hash")
            return recorded, None
        return recorded or rihs01(name), cdr_codec(ros2_type(name))
    except Unplayable:
        raise
    except Exception as exc:    # a nested type neither in the schema nor known here, or one rosbags refuses
        raise Unplayable(f"its definition cannot be used: {_one_line(exc)}") from None


def _one_line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())


def channel_qos(metadata: dict[str, str]) -> QoSProfile:
    """The QoS a channel's publisher offered (see the module doc)."""
    if "zr.qos" in metadata:
        with contextlib.suppress(ValueError, KeyError):
            return decode_qos(metadata["zr.qos"])
    offered = metadata.get("offered_qos_profiles", "")
    if offered:
        with contextlib.suppress(Exception):   # a profile we cannot read is the default, not a failure
            return _rosbag2_qos(offered)
    return QoSProfile()


def _rosbag2_qos(text: str) -> QoSProfile:
    import yaml

    profiles = yaml.safe_load(text)
    if not isinstance(profiles, list) or not profiles or not all(isinstance(p, dict) for p in profiles):
        return QoSProfile()
    # rosbag2 writes the policies as numbers (Humble, Iron) or as names (Jazzy and newer)
    reliable = all(str(p.get("reliability", 1)).lower() in ("1", "reliable") for p in profiles)
    kept = all(str(p.get("durability", 2)).lower() in ("1", "transient_local") for p in profiles)
    depth = max((int(p.get("depth", 0) or 0) for p in profiles), default=0)
    return QoSProfile(ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      DurabilityPolicy.TRANSIENT_LOCAL if kept else DurabilityPolicy.VOLATILE,
                      depth=depth if depth > 0 else 10)


class Ros2Sender:
    """One channel's ROS 2 publisher on ``node``'s session: its token, its Zenoh publisher, its sequence."""

    def __init__(self, node: "Node", wire: Ros2WireFormat, channel: Ros2Channel, ident: int) -> None:
        graph = wire.graph
        assert isinstance(graph, Ros2Graph)
        key = graph.entity_token(PUBLISHER, node.zid, ident, node.get_namespace(), node.name, channel.topic,
                                 channel.type_name, channel.type_hash, channel.qos)
        self.channel = channel
        self._gid = token_gid(key)
        self._token = node.session.liveliness().declare_token(key)
        data_key = f"{wire.domain_id}/{channel.topic[1:]}/{dds_type_name(channel.type_name)}/{channel.type_hash}"
        self._zpub = declare_publisher(node.session, data_key, channel.qos)
        self._seq = 0

    def put(self, payload: bytes, stamp_ns: int) -> None:
        self._seq += 1
        self._zpub.put(payload, attachment=pack_attachment(self._seq, stamp_ns, self._gid))

    def close(self) -> None:
        for handle in (self._token, self._zpub):
            with contextlib.suppress(Exception):
                handle.undeclare()


def node_token(node: "Node", wire: Ros2WireFormat) -> str:
    """The ``NN`` token of ``node`` on ``wire`` (for a player whose node speaks another format)."""
    return wire.graph.node_token(NodeInfo(node.name, node.get_namespace(), node.zid))
