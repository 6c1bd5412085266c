"""ROS 2's wire format, rmw_zenoh's (Jazzy 0.2.4+, Kilted, Rolling): a node with
``wire=ros2_wire(domain_id)`` is a ROS 2 node to any rmw_zenoh peer, and sees them.

- Data key ``<domain>/<topic>/<pkg>::msg::dds_::<Type>_/RIHS01_<sha256>``: a type or hash
  mismatch means no match at all, as between rmw_zenoh nodes.
- Payload: the type's CDR (encapsulation header ``00 01 00 00``, little-endian XCDR1), made by
  the type's codec (``zenoh_robot.ros2``: a type without a ROS 2 definition is refused).
- Attachment on every put: int64 LE sequence, int64 LE source stamp (ns), the byte 16, the
  16-byte GID (33 bytes). The GID is rmw_zenoh's: XXH3-128 of the entity's liveliness token.
- Graph: ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/<NN|MP|MS|SS|SC>/<enclave>/<ns>/<node>/<topic>/
  <type>/<hash>/<qos>``, ``/`` mangled to ``%``, the QoS with explicit values (the defaults that
  older rmw_zenoh elided changed between versions; both forms are read).

Ids: our tokens carry, as the entity id, the endpoint's id xor a value of the session's zid, so
a token read back gives the endpoint's own id (``Publisher.gid``: what its liveliness heartbeats
carry); a ROS peer's entity ids (a counter per session) become unique ids the same way. A
sample's publisher id is that id, found from the attachment's GID through the tokens seen
(:class:`GidTable`); a GID whose token was not seen yet gives its own 63-bit fold.

Threading: the format and its graph are shared by every node of a process that uses the
domain; the GID table is locked and bounded.
"""
from __future__ import annotations

import os
import struct
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from ..envelope import MalformedSample
from ..graph import ANY_TYPE_HASH, EndpointType, NodeInfo, TopicEndpointInfo
from ..qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from .format import Decoder, GraphFormat, Header

if TYPE_CHECKING:
    from ..message import TypeSupport

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION, SERVICE, CLIENT = "NN", "MP", "MS", "SS", "SC"
ATTACHMENT = struct.Struct("<qqB16s")
ATTACHMENT_SIZE = ATTACHMENT.size            # 33
CDR_HEADER = b"\x00\x01\x00\x00"            # CDR_LE, options 0
_MASK63 = (1 << 63) - 1
# RMW_DURATION_INFINITE: what "no deadline / lifespan / lease" is written as.
INFINITE = (9223372036, 854775807)


class Ros2Codec(Protocol):
    """What the format needs of a ROS 2 type (``zenoh_robot.ros2.Ros2Codec``)."""
    dds_name: str

    def serialize(self, body: Any) -> bytes: ...

    def deserialize(self, payload: bytes | memoryview, *, cut_trailing: bool = False) -> list[Any]: ...


# -- names ------------------------------------------------------------------------------------
def mangle(text: str) -> str:
    """rmw_zenoh's mangling of a token field: ``/`` -> ``%``; an empty field is ``%``."""
    return text.replace("/", "%") if text else "%"


def unmangle(text: str) -> str:
    return text.replace("%", "/")


def dds_type_name(ros_name: str) -> str:
    """``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_`` (``pkg/srv/S`` likewise)."""
    parts = ros_name.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"a ROS 2 type name is pkg/msg/Type, got {ros_name!r}")
    return f"{parts[0]}::{parts[1]}::dds_::{parts[2]}_"


def ros_type_name(dds_name: str) -> str:
    """The inverse of :func:`dds_type_name`; ValueError for anything else."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_") or len(parts[3]) < 2:
        raise ValueError(f"not a ROS 2 DDS type name: {dds_name!r}")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


# -- attachment and GIDs ------------------------------------------------------------------------
def pack_attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment rmw_zenoh puts on every sample, query and reply."""
    if len(gid) != 16:
        raise ValueError(f"a GID is 16 bytes, got {len(gid)}")
    return ATTACHMENT.pack(seq, stamp_ns, 16, gid)


class LegacyAttachment(MalformedSample):
    """The labelled attachment of rmw_zenoh Jazzy <= 0.2.3, which current rmw_zenoh rejects too."""


_LEGACY_LABELS = (b"sequence_number", b"source_timestamp", b"source_gid")


def unpack_attachment(data: bytes | None) -> tuple[int, int, bytes]:
    """(seq, stamp_ns, gid) of an attachment; MalformedSample for anything but the 33-byte form
    (LegacyAttachment for the labelled one of rmw_zenoh <= 0.2.3: a peer to name, not just drop)."""
    if data is None:
        raise MalformedSample("no attachment (rmw_zenoh sends seq, stamp and GID: 33 bytes)")
    if len(data) != ATTACHMENT_SIZE or data[16] != 16:
        if any(label in data for label in _LEGACY_LABELS):
            from ..ros2.compat import note_legacy_attachment  # counted and named once per peer
            note_legacy_attachment(data, "a ROS 2 topic or service")
            raise LegacyAttachment("legacy labelled attachment of rmw_zenoh <= 0.2.3 (Jazzy); "
                                   "current rmw_zenoh uses 33 bytes: seq, stamp, 16, GID")
        raise MalformedSample(f"attachment of {len(data)} bytes is not rmw_zenoh's 33-byte form "
                              "(seq, stamp, gid)")
    seq, stamp, _, gid = ATTACHMENT.unpack(data)
    return int(seq), int(stamp), bytes(gid)


def token_gid(token_key: str) -> bytes:
    """An entity's GID as rmw_zenoh makes it: XXH3-128 of its liveliness token, low 64 bits then high,
    each little-endian."""
    import xxhash  # only ROS 2 nodes need it (the ros2 extra)

    return int(xxhash.xxh3_128_intdigest(token_key.encode())).to_bytes(16, "little")


def gid_to_id(gid: bytes) -> int:
    """The 63-bit id of a GID whose token is unknown."""
    return int.from_bytes(gid[:8], "little") & _MASK63


def _zid_salt(zid: str) -> int:
    import xxhash

    return int(xxhash.xxh3_64_intdigest(zid.encode())) & _MASK63


def node_id(namespace: str, name: str) -> int:
    """The node id (``nid``) our tokens carry: fixed by the node's full name."""
    import xxhash

    return int(xxhash.xxh3_64_intdigest(f"{namespace}/{name}".encode())) & 0x7FFFFFFF


class GidTable:
    """GID -> endpoint id of the tokens seen (bounded LRU; locked)."""

    def __init__(self, cap: int = 8192) -> None:
        self._lock = threading.Lock()
        self._ids: OrderedDict[bytes, int] = OrderedDict()
        self._gids: dict[int, bytes] = {}
        self._cap = cap

    def put(self, gid: bytes, ident: int) -> None:
        with self._lock:
            self._ids[gid] = ident
            self._ids.move_to_end(gid)
            self._gids[ident] = gid
            while len(self._ids) > self._cap:
                _, old = self._ids.popitem(last=False)
                self._gids.pop(old, None)

    def gid_of(self, ident: int) -> bytes:
        """The GID of the token last made or seen for ``ident``; without one, 16 bytes of the id."""
        with self._lock:
            gid = self._gids.get(ident)
        return gid if gid is not None else ident.to_bytes(16, "little")

    def get(self, gid: bytes) -> int:
        ident = self._ids.get(gid)      # a dict read is atomic: no lock per sample
        return gid_to_id(gid) if ident is None else ident


# -- QoS ------------------------------------------------------------------------------------
def _dur(seconds: float | None) -> str:
    if seconds is None:
        return f"{INFINITE[0]},{INFINITE[1]}"
    ns = int(round(seconds * 1e9))
    return f"{ns // 1_000_000_000},{ns % 1_000_000_000}"


def _seconds(sec: str, nsec: str) -> float | None:
    if not sec and not nsec:
        return None
    s, n = int(sec or 0), int(nsec or 0)
    if (s, n) == INFINITE or (s, n) == (0, 0) or s >= INFINITE[0]:
        return None     # infinite, or unspecified (which ROS 2 reads as infinite)
    return s + n / 1e9


def encode_ros2_qos(q: QoSProfile) -> str:
    """rmw_zenoh's QoS field with every value explicit:
    ``reliability:durability:history,depth:deadline_s,ns:lifespan_s,ns:liveliness,lease_s,ns``."""
    depth = q.depth if q.history is not HistoryPolicy.KEEP_ALL else 0
    return ":".join([str(q.reliability.value), str(q.durability.value), f"{q.history.value},{depth}",
                     _dur(q.deadline), _dur(q.lifespan), f"{q.liveliness.value},{_dur(q.liveliness_lease_duration)}"])


def decode_ros2_qos(text: str) -> QoSProfile:
    """A QoS field back into a profile (empty parts: rmw_zenoh's defaults); ValueError if malformed."""
    parts = text.split(":")
    if len(parts) != 6:
        raise ValueError(f"QoS field has {len(parts)} parts, expected 6: {text!r}")
    hist = parts[2].split(",")
    deadline, lifespan, live = parts[3].split(","), parts[4].split(","), parts[5].split(",")
    if len(hist) != 2 or len(deadline) != 2 or len(lifespan) != 2 or len(live) != 3:
        raise ValueError(f"malformed QoS field {text!r}")
    reliability = ReliabilityPolicy.BEST_EFFORT if parts[0] == "2" else ReliabilityPolicy.RELIABLE
    durability = DurabilityPolicy.TRANSIENT_LOCAL if parts[1] == "1" else DurabilityPolicy.VOLATILE
    history = HistoryPolicy.KEEP_ALL if hist[0] == "2" else HistoryPolicy.KEEP_LAST
    depth = int(hist[1]) if hist[1] else 10
    liveliness = LivelinessPolicy.MANUAL_BY_TOPIC if live[0] in ("2", "3") else LivelinessPolicy.AUTOMATIC
    return QoSProfile(reliability, durability, history, depth if history is HistoryPolicy.KEEP_LAST else 10,
                      _seconds(*deadline), _seconds(*lifespan), liveliness, _seconds(live[1], live[2]))


# -- the graph ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Ros2Token:
    """Every field of an ``@ros2_lv`` token (services and clients too)."""
    kind: str            # NN, MP, MS, SS, SC
    domain_id: int
    zid: str
    nid: str
    eid: str
    enclave: str
    namespace: str       # "/" or "/uav1"
    node: str
    name: str = ""       # the topic or service, "/chatter"
    type_name: str = ""  # ROS form: std_msgs/msg/String ("" if not a ROS type name)
    type_hash: str = ""
    qos: QoSProfile | None = None
    raw_type: str = ""   # as in the token: std_msgs::msg::dds_::String_


def parse_any_token(key: str) -> Ros2Token:
    """Any ``@ros2_lv`` token; ValueError for another key."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        raise ValueError(f"not an @ros2_lv token: {key!r}")
    _, domain, zid, nid, eid, kind, enclave, ns, node = parts[:9]
    head = (int(domain), zid, nid, eid, unmangle(enclave), "/" + unmangle(ns).strip("/"), unmangle(node))
    if kind == NODE and len(parts) == 9:
        return Ros2Token(kind, *head)
    if kind not in (PUBLISHER, SUBSCRIPTION, SERVICE, CLIENT) or len(parts) != 13:
        raise ValueError(f"not an @ros2_lv entity token: {key!r}")
    name, raw_type, type_hash, qos = parts[9:]
    try:
        type_name = ros_type_name(raw_type)
    except ValueError:
        type_name = ""
    # Demangled verbatim, as rmw_zenoh's graph cache does: a name written without its leading '%'
    # is not the fully qualified name any ROS 2 client asks for, and must not be read as if it were.
    return Ros2Token(kind, *head, unmangle(name), type_name, type_hash, decode_ros2_qos(qos), raw_type)


class Ros2Graph:
    """The ``@ros2_lv`` tokens of one domain as a :class:`~zenoh_robot.wire.GraphFormat`."""

    def __init__(self, domain_id: int, gids: GidTable | None = None) -> None:
        self.domain_id = domain_id
        self.selector = f"{ADMIN_SPACE}/{domain_id}/**"
        self.gids = gids if gids is not None else GidTable()

    def node_token(self, info: NodeInfo) -> str:
        nid = node_id(info.namespace, info.name)
        return "/".join([ADMIN_SPACE, str(self.domain_id), info.zid, str(nid), str(nid), NODE, "%",
                         mangle(info.namespace), mangle(info.name)])

    def node_selector(self, namespace: str, node_name: str) -> str:
        return "/".join([ADMIN_SPACE, str(self.domain_id), "*", "*", "*", NODE, "*",
                         mangle("/" + namespace if namespace else "/"), mangle(node_name)])

    def entity_token(self, kind: str, zid: str, ident: int, namespace: str, node: str, name: str, type_name: str,
                     type_hash: str, qos: QoSProfile) -> str:
        """The token of one endpoint (``kind`` MP, MS, SS or SC) whose id is ``ident`` (its ``gid``):
        a token read back by :meth:`parse_token` gives that id again."""
        eid = (ident ^ _zid_salt(zid)) & _MASK63
        raw_type = dds_type_name(type_name) if type_name else "%"
        # rmw_zenoh writes the fully qualified name ("/zr/set_flag" -> "%zr%set_flag"): its graph matches
        # a client's wait_for_service() and `ros2 service list` against that exact string.
        qualified = "/" + name.lstrip("/")
        key = "/".join([ADMIN_SPACE, str(self.domain_id), zid, str(node_id(namespace, node)), str(eid), kind, "%",
                        mangle(namespace), mangle(node), mangle(qualified), raw_type,
                        type_hash if type_hash != ANY_TYPE_HASH and type_hash else "%", encode_ros2_qos(qos)])
        self.gids.put(token_gid(key), ident)
        return key

    def endpoint_token(self, info: TopicEndpointInfo) -> str:
        kind = PUBLISHER if info.endpoint_type is EndpointType.PUBLISHER else SUBSCRIPTION
        return self.entity_token(kind, info.zid, info.endpoint_gid, info.node_namespace, info.node_name,
                                 info.topic_name, info.topic_type, info.topic_type_hash, info.qos_profile)

    def endpoint_id(self, token: Ros2Token) -> int:
        """The id of a token's entity (see the module doc)."""
        return (int(token.eid) ^ _zid_salt(token.zid)) & _MASK63

    def parse_token(self, key: str) -> NodeInfo | TopicEndpointInfo:
        from ..ros2.compat import note_token  # a Humble peer (no type hash): counted and named once
        note_token(key)
        token = parse_any_token(key)
        if token.domain_id != self.domain_id:
            raise ValueError(f"token of domain {token.domain_id}, not {self.domain_id}")
        if token.kind == NODE:
            return NodeInfo(token.node, token.namespace, token.zid)
        if token.kind not in (PUBLISHER, SUBSCRIPTION):
            raise ValueError(f"a service token ({token.kind}), not a topic endpoint: {key!r}")
        if not token.name.startswith("/"):
            raise ValueError(f"topic {token.name!r} is not fully qualified (rmw_zenoh writes '%topic'): {key!r}")
        ident = self.endpoint_id(token)
        self.gids.put(token_gid(key), ident)
        type_hash = ANY_TYPE_HASH if token.type_hash == "%" else token.type_hash
        return TopicEndpointInfo(token.node, token.namespace, token.name, token.type_name, type_hash,
                                 EndpointType.PUBLISHER if token.kind == PUBLISHER else EndpointType.SUBSCRIPTION,
                                 ident, token.qos or QoSProfile(), token.zid)


# -- samples -------------------------------------------------------------------------------------
def _codec(type_support: TypeSupport) -> Ros2Codec:
    codec = type_support.msg_type.__dict__.get("_zr_ros2")
    if codec is None:
        raise TypeError(f"{type_support.name} has no ROS 2 definition: on a ROS 2 wire node use "
                        "zenoh_robot.ros2.ros2_type('pkg/msg/Type') (or load_ros2_msg)")
    return codec  # type: ignore[no-any-return]


class Ros2Encoder:
    """One publisher's encoder: CDR payload, and the attachment with its GID (found once its token is
    declared, which the publisher does before its first sample)."""

    def __init__(self, codec: Ros2Codec, publisher_id: int, gids: GidTable) -> None:
        self._serialize = codec.serialize
        self._publisher_id = publisher_id
        self._gids = gids
        self._gid: bytes | None = None

    def pack(self, seq: int, stamp_ns: int, body: Any, extra: dict[str, Any] | None = None) -> bytes:
        if extra:
            raise ValueError("the ros2 wire format carries no extra fields")
        return self._serialize(body)

    def attachment(self, seq: int, stamp_ns: int) -> bytes:
        gid = self._gid
        if gid is None:
            gid = self._gid = self._gids.gid_of(self._publisher_id)
        return ATTACHMENT.pack(seq, stamp_ns, 16, gid)


class Ros2WireFormat:
    """The :class:`~zenoh_robot.wire.WireFormat` of rmw_zenoh (the module doc); use :func:`ros2_wire`."""

    name = "ros2"
    carries_extra = False
    uses_attachment = True

    def __init__(self, domain_id: int = 0) -> None:
        if not 0 <= int(domain_id) <= 232:
            raise ValueError(f"ROS domain id {domain_id} out of 0..232")
        self.domain_id = int(domain_id)
        self.gids = GidTable()
        # Typed as the seam's (WireFormat.graph is a GraphFormat); isinstance gives back Ros2Graph.
        self.graph: GraphFormat = Ros2Graph(self.domain_id, self.gids)

    def data_key(self, topic_key: str, type_support: TypeSupport | None) -> str:
        if type_support is None:
            return f"{self.domain_id}/{topic_key}/*/*"
        return f"{self.domain_id}/{topic_key}/{_codec(type_support).dds_name}/{type_support.hash}"

    def encoder(self, type_support: TypeSupport, publisher_id: int) -> Ros2Encoder:
        return Ros2Encoder(_codec(type_support), publisher_id, self.gids)

    def decoder(self, type_support: TypeSupport | None) -> Decoder:
        gids = self.gids
        if type_support is None:
            def decode_any(payload: bytes, attachment: bytes | None) -> Header:
                seq, stamp, gid = unpack_attachment(attachment)
                return "", "", gids.get(gid), seq, stamp, payload, {}
            return decode_any
        codec = _codec(type_support)
        deserialize = codec.deserialize
        generated = getattr(codec, "fast", None)      # the generated codec, when the type has one
        fast: Callable[[bytes, bool], list[Any]] | None = generated.decode if generated is not None else None
        name, type_hash = type_support.name, type_support.hash
        unpack, cdr_le = ATTACHMENT.unpack, CDR_HEADER[:2]

        def decode(payload: bytes, attachment: bytes | None) -> Header:
            # The hot path (issue #30): the common attachment unpacked here, the generated decoder called
            # directly; anything else goes the long way, which names what is wrong.
            if attachment is None or len(attachment) != ATTACHMENT_SIZE or attachment[16] != 16:
                seq, stamp, gid = unpack_attachment(attachment)     # raises for all but the 33-byte form
            else:
                seq, stamp, _, gid = unpack(attachment)
            if payload[:2] != cdr_le:
                raise MalformedSample(f"not little-endian CDR (encapsulation {bytes(payload[:4]).hex()})")
            try:
                # Bytes after the body are not read, as rmw_zenoh's Fast-CDR does not read them: PX4's zenoh
                # module sends its uORB buffer's capacity (0-31 leftover bytes), and a strict reader would see
                # none of PX4's topics. A body that does not fit is still refused.
                body = fast(payload, True) if fast is not None else deserialize(payload, cut_trailing=True)
            except Exception:
                try:     # rosbags names what is wrong (or decodes what the generated codec did not foresee)
                    body = deserialize(payload, cut_trailing=True)
                except Exception as exc:    # rosbags raises several kinds for truncated or foreign bytes
                    raise MalformedSample(f"CDR does not decode as {name}: {type(exc).__name__}: {exc}") from None
            return name, type_hash, gids.get(gid), seq, stamp, body, {}
        return decode

    def __repr__(self) -> str:
        return f"ros2_wire({self.domain_id})"


_WIRES: dict[int, Ros2WireFormat] = {}
_WIRES_LOCK = threading.Lock()


def ros2_wire(domain_id: int | None = None) -> Ros2WireFormat:
    """The ROS 2 wire format of a domain (None: ``ROS_DOMAIN_ID`` or 0), one shared instance per domain."""
    if domain_id is None:
        domain_id = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    with _WIRES_LOCK:
        wire = _WIRES.get(domain_id)
        if wire is None:
            wire = _WIRES[domain_id] = Ros2WireFormat(domain_id)
        return wire
