"""The ROS graph over Zenoh liveliness tokens: who publishes and subscribes what, with which QoS.

Every node, publisher and subscription declares a liveliness token whose key says
all about it (rmw_zenoh does the same)::

    @zr/lv/NN/<zid>/0/<ns>/<node>                                   a node
    @zr/lv/MP/<zid>/<gid>/<ns>/<node>/<topic>/<type>/<hash>/<qos>   a publisher (MS: a subscription)

``/`` inside a field becomes ``%`` (an empty field is ``%``). Zenoh removes a token
when its session closes or its process dies (the transport closes or its lease
expires), so every node's view follows processes coming and going with no
heartbeat of ours. ``@zr`` is a verbatim chunk: ``**`` on data keys never sees it.

That token scheme is the envelope format's (``ZR_GRAPH``); the graph machinery here
(:class:`GraphCache`, :class:`Graph`, :func:`ensure_unique_node`) works with any
:class:`~zenoh_robot.wire.GraphFormat`, the one of the node's wire format.
"""
from __future__ import annotations

import enum
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import zenoh

from .context import Endpoint
from .qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, Priority, QoSProfile, ReliabilityPolicy

if TYPE_CHECKING:
    from .wire.format import GraphFormat

log = logging.getLogger("zenoh_robot.graph")

GRAPH_PREFIX = "@zr/lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
# The type hash a raw subscription of any type announces: it matches every publisher's type.
ANY_TYPE_HASH = "any"
# Tokens kept that are no node or topic endpoint (services, clients): bounded against a flood of junk keys.
MAX_OTHER_TOKENS = 65536


class EndpointType(enum.Enum):
    PUBLISHER = "publisher"
    SUBSCRIPTION = "subscription"


@dataclass(frozen=True)
class TopicEndpointInfo:
    """One publisher or subscription somewhere on the network (rclpy's shape)."""
    node_name: str
    node_namespace: str
    topic_name: str          # "/uav1/setpoint"
    topic_type: str
    topic_type_hash: str
    endpoint_type: EndpointType
    endpoint_gid: int        # the publisher id that its samples carry
    qos_profile: QoSProfile
    zid: str = ""

    @property
    def key(self) -> str:
        return self.topic_name[1:]


@dataclass(frozen=True)
class NodeInfo:
    name: str
    namespace: str           # "/" or "/uav1"
    zid: str = ""


def _mangle(text: str) -> str:
    return text.replace("/", "%") if text else "%"


def _unmangle(text: str) -> str:
    return "" if text == "%" else text.replace("%", "/")


def _ns(seconds: float | None) -> str:
    return "" if seconds is None else str(int(round(seconds * 1e9)))


def _seconds(text: str) -> float | None:
    return None if text == "" else int(text) / 1e9


def encode_qos(q: QoSProfile) -> str:
    return ":".join([str(q.reliability.value), str(q.durability.value), str(q.history.value), str(q.depth),
                     _ns(q.deadline), _ns(q.lifespan), str(q.liveliness.value), _ns(q.liveliness_lease_duration),
                     str(q.priority.value), "1" if q.express else "0", str(q.redundancy), str(q.repeat)])


def decode_qos(text: str) -> QoSProfile:
    f = text.split(":")
    if len(f) != 12:
        raise ValueError(f"QoS field has {len(f)} parts, expected 12")
    return QoSProfile(ReliabilityPolicy(int(f[0])), DurabilityPolicy(int(f[1])), HistoryPolicy(int(f[2])), int(f[3]),
                      _seconds(f[4]), _seconds(f[5]), LivelinessPolicy(int(f[6])), _seconds(f[7]),
                      Priority(int(f[8])), f[9] == "1", int(f[10]), int(f[11]))


def endpoint_token_key(kind: str, zid: str, gid: int, namespace: str, node: str, topic_key: str,
                       type_name: str, type_hash: str, qos: QoSProfile) -> str:
    return "/".join([GRAPH_PREFIX, kind, zid, str(gid), _mangle(namespace), node, _mangle(topic_key),
                     _mangle(type_name), type_hash, encode_qos(qos)])


def node_token_key(zid: str, namespace: str, node: str) -> str:
    return "/".join([GRAPH_PREFIX, NODE, zid, "0", _mangle(namespace), node])


def parse_token(key: str) -> NodeInfo | TopicEndpointInfo:
    """A token key back into what it announces; ValueError for a key not in our format."""
    parts = key.split("/")
    if len(parts) < 7 or "/".join(parts[:2]) != GRAPH_PREFIX:
        raise ValueError(f"not a graph token: {key!r}")
    kind, zid, gid, ns, node = parts[2:7]
    namespace = "/" + _unmangle(ns)
    if kind == NODE and len(parts) == 7:
        return NodeInfo(node, namespace, zid)
    if kind not in (PUBLISHER, SUBSCRIPTION) or len(parts) != 11:
        raise ValueError(f"not a graph token: {key!r}")
    topic, type_name, type_hash, qos = parts[7:11]
    return TopicEndpointInfo(node, namespace, "/" + _unmangle(topic), _unmangle(type_name), type_hash,
                             EndpointType.PUBLISHER if kind == PUBLISHER else EndpointType.SUBSCRIPTION,
                             int(gid), decode_qos(qos), zid)


class ZrGraphFormat:
    """The envelope format's tokens (the module doc) as a :class:`~zenoh_robot.wire.GraphFormat`:
    use the instance ``ZR_GRAPH``."""

    selector = f"{GRAPH_PREFIX}/**"

    def node_token(self, info: NodeInfo) -> str:
        return node_token_key(info.zid, info.namespace.strip("/"), info.name)

    def node_selector(self, namespace: str, node_name: str) -> str:
        return "/".join([GRAPH_PREFIX, NODE, "*", "*", _mangle(namespace), node_name])

    def endpoint_token(self, info: TopicEndpointInfo) -> str:
        kind = PUBLISHER if info.endpoint_type is EndpointType.PUBLISHER else SUBSCRIPTION
        return endpoint_token_key(kind, info.zid, info.endpoint_gid, info.node_namespace.strip("/"), info.node_name,
                                  info.key, info.topic_type, info.topic_type_hash, info.qos_profile)

    def parse_token(self, key: str) -> NodeInfo | TopicEndpointInfo:
        return parse_token(key)


ZR_GRAPH = ZrGraphFormat()

GraphListener = Callable[[bool, TopicEndpointInfo], None]


class GraphCache:
    """This process's view of the graph, kept by a liveliness subscriber (one per node).

    Listeners run on Zenoh's thread with ``(appeared, info)``: they must only hand work on.
    """

    def __init__(self, session: zenoh.Session, graph_format: GraphFormat) -> None:
        self._session = session
        self._format = graph_format
        self._lock = threading.Lock()
        self._entries: dict[str, NodeInfo | TopicEndpointInfo] = {}
        # Live tokens of the selector that are not nodes or topic endpoints (a ROS 2 graph's SS/SC): kept so a
        # listing can read them from this subscriber, and counted as changes so "settled" covers them too.
        self._others: set[str] = set()
        self.listeners: list[GraphListener] = []
        self.changes = 0
        self._changed = threading.Condition(self._lock)
        self._sub = session.liveliness().declare_subscriber(graph_format.selector, self._on_token, history=True)

    def _on_token(self, sample: Any) -> None:
        key = str(sample.key_expr)
        appeared = sample.kind == zenoh.SampleKind.PUT
        self._apply(key, appeared)

    def _apply(self, key: str, appeared: bool) -> None:
        try:
            info = self._format.parse_token(key)
        except (ValueError, KeyError) as exc:
            log.debug("graph token %r is no node or topic endpoint: %s", key, exc)
            self._apply_other(key, appeared)
            return
        with self._lock:
            known = key in self._entries
            if appeared == known:
                return     # a history reply and a live put can both announce one token
            if appeared:
                self._entries[key] = info
            else:
                del self._entries[key]
            self.changes += 1
            self._changed.notify_all()
            listeners = list(self.listeners)
        if isinstance(info, TopicEndpointInfo):
            for listener in listeners:
                try:
                    listener(appeared, info)
                except Exception:
                    log.exception("graph listener failed")

    def _apply_other(self, key: str, appeared: bool) -> None:
        with self._lock:
            if appeared == (key in self._others) or (appeared and len(self._others) >= MAX_OTHER_TOKENS):
                return
            if appeared:
                self._others.add(key)
            else:
                self._others.discard(key)
            self.changes += 1
            self._changed.notify_all()

    def refresh(self, timeout: float = 1.0) -> None:
        """Ask the network for every live token now (a late start need not wait for history)."""
        replies = self._session.liveliness().get(self._format.selector, timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                self._apply(str(reply.ok.key_expr), True)

    def wait_for_change(self, since: int, timeout: float) -> bool:
        with self._lock:
            return self._changed.wait_for(lambda: self.changes != since, timeout)

    def nodes(self) -> list[NodeInfo]:
        with self._lock:
            return [e for e in self._entries.values() if isinstance(e, NodeInfo)]

    def endpoints(self, key: str | None = None, kind: EndpointType | None = None) -> list[TopicEndpointInfo]:
        with self._lock:
            return [e for e in self._entries.values() if isinstance(e, TopicEndpointInfo)
                    and (key is None or e.key == key) and (kind is None or e.endpoint_type is kind)]

    def other_tokens(self) -> list[str]:
        """The live tokens that are not nodes or topic endpoints (on the ROS 2 wire: services and clients)."""
        with self._lock:
            return sorted(self._others)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass


class Graph:
    """One node's part in the graph: its node token, its endpoints' tokens, and the network's view.

    The node owns one and delegates rclpy's graph methods to it. Local endpoints register
    here so the graph tells them about peers on their key (on Zenoh's thread: they only
    hand work on).
    """

    def __init__(self, session: zenoh.Session, namespace: str, node_name: str, graph_format: GraphFormat) -> None:
        self._session = session
        self._namespace = namespace
        self._node_name = node_name
        self._format = graph_format
        self._lock = threading.Lock()
        self._local: list[tuple[EndpointType, Endpoint]] = []
        self.zid = str(session.info.zid())
        self.cache = GraphCache(session, graph_format)
        self.cache.listeners.append(self._on_graph_change)
        self._node_token: Any = None
        try:
            self._node_token = session.liveliness().declare_token(
                graph_format.node_token(NodeInfo(node_name, "/" + namespace, self.zid)))
        except BaseException:
            self.cache.close()
            raise

    # -- local endpoints ---------------------------------------------------------------
    def declare_endpoint(self, kind: EndpointType, entity: Endpoint) -> Any:
        """Announce ``entity`` (a token) and tell it about the peers already known."""
        key = self._format.endpoint_token(TopicEndpointInfo(
            self._node_name, "/" + self._namespace, "/" + entity.key, entity.type_name, entity.type_hash, kind,
            entity.gid, entity.qos, self.zid))
        token = self._session.liveliness().declare_token(key)
        peers = EndpointType.SUBSCRIPTION if kind is EndpointType.PUBLISHER else EndpointType.PUBLISHER
        entry = (peers, entity)
        with self._lock:    # listen first, then read what is known: a peer may be reported twice, never missed
            self._local.append(entry)
        for info in self.cache.endpoints(entity.key, peers):
            entity.on_peer(True, info)
        return _EndpointToken(token, lambda: self._forget(entry))

    def _forget(self, entry: tuple[EndpointType, Endpoint]) -> None:
        with self._lock:
            if entry in self._local:
                self._local.remove(entry)

    def _on_graph_change(self, appeared: bool, info: TopicEndpointInfo) -> None:
        # Zenoh's thread: tell the local entities that want that kind of peer on that key.
        with self._lock:
            entries = list(self._local)
        for peers, entity in entries:
            if peers is info.endpoint_type and entity.key == info.key:
                entity.on_peer(appeared, info)

    # -- rclpy's graph API ------------------------------------------------------------
    def refresh(self, timeout: float = 1.0) -> None:
        self.cache.refresh(timeout)

    def get_node_names(self) -> list[str]:
        return sorted({n.name for n in self.cache.nodes()})

    def get_node_names_and_namespaces(self) -> list[tuple[str, str]]:
        return sorted({(n.name, n.namespace) for n in self.cache.nodes()})

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        topics: dict[str, set[str]] = {}
        for e in self.cache.endpoints():
            types = topics.setdefault(e.topic_name, set())
            if e.topic_type:      # a raw subscription of any type names none
                types.add(e.topic_type)
        return [(name, sorted(types)) for name, types in sorted(topics.items())]

    def endpoints_by_key(self, key: str, kind: EndpointType) -> list[TopicEndpointInfo]:
        return self.cache.endpoints(key, kind)

    def close(self) -> None:
        self.cache.close()
        if self._node_token is not None:
            try:
                self._node_token.undeclare()
            except Exception:
                pass


class _EndpointToken:
    """An endpoint's liveliness token; undeclaring it also stops the graph's peer reports."""

    def __init__(self, token: Any, forget: Callable[[], None]) -> None:
        self._token = token
        self._forget = forget

    def undeclare(self) -> None:
        self._forget()
        self._token.undeclare()


class DuplicateNodeError(RuntimeError):
    """A node with this fully qualified name is already alive in this domain."""


def live_node_owners(session: zenoh.Session, namespace: str, node_name: str, graph_format: GraphFormat,
                     timeout: float = 0.5) -> list[str]:
    """Zenoh ids of *other* sessions holding a live node token for ``namespace``/``node_name``."""
    own = str(session.info.zid())
    owners = []
    for reply in session.liveliness().get(graph_format.node_selector(namespace, node_name), timeout=timeout):
        if reply.ok is not None:
            try:
                zid = graph_format.parse_token(str(reply.ok.key_expr)).zid
            except (ValueError, KeyError):
                continue
            if zid and zid != own and zid not in owners:
                owners.append(zid)
    return owners


def ensure_unique_node(session: zenoh.Session, namespace: str, node_name: str, graph_format: GraphFormat,
                       timeout: float = 0.5) -> None:
    """Refuse a second node of the same name: two ``--id uav1`` companions would merge silently.

    One query, answered at once with what this session's routing already knows: right after
    ``open`` that is often nothing (issue #42). It stays as the quick check against nodes that hold
    no claim (another wire format's peers); ``zenoh_robot.claim`` is the race-free one.
    """
    owners = live_node_owners(session, namespace, node_name, graph_format, timeout)
    if not owners:
        return
    where = {str(link.zid): str(link.dst) for link in session.info.links()}
    fqn = f"/{namespace}/{node_name}" if namespace else f"/{node_name}"
    others = ", ".join(f"zid {z} at {where[z]}" if z in where else f"zid {z} (via a router)" for z in owners)
    raise DuplicateNodeError(f"node {fqn} is already running in this domain ({others}): "
                             "stop it, or give this one another name/namespace or --domain")
