"""The ROS graph over Zenoh liveliness tokens: who publishes and subscribes what, with which QoS.

Every node, publisher and subscription declares a liveliness token whose key says
all about it (rmw_zenoh does the same)::

    @zr/lv/NN/<zid>/0/<ns>/<node>                                   a node
    @zr/lv/MP/<zid>/<gid>/<ns>/<node>/<topic>/<type>/<hash>/<qos>   a publisher (MS: a subscription)

``/`` inside a field becomes ``%`` (an empty field is ``%``). Zenoh removes a token
when its session closes or its process dies (the transport closes or its lease
expires), so every node's view follows processes coming and going with no
heartbeat of ours. ``@zr`` is a verbatim chunk: ``**`` on data keys never sees it.
"""
from __future__ import annotations

import enum
import logging
import threading
from dataclasses import dataclass
from typing import Any, Callable

import zenoh

from .qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, Priority, QoSProfile, ReliabilityPolicy

log = logging.getLogger("zenoh_robot.graph")

GRAPH_PREFIX = "@zr/lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"


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


GraphListener = Callable[[bool, TopicEndpointInfo], None]


class GraphCache:
    """This process's view of the graph, kept by a liveliness subscriber (one per node).

    Listeners run on Zenoh's thread with ``(appeared, info)``: they must only hand work on.
    """

    def __init__(self, session: zenoh.Session) -> None:
        self._session = session
        self._lock = threading.Lock()
        self._entries: dict[str, NodeInfo | TopicEndpointInfo] = {}
        self.listeners: list[GraphListener] = []
        self.changes = 0
        self._changed = threading.Condition(self._lock)
        self._sub = session.liveliness().declare_subscriber(f"{GRAPH_PREFIX}/**", self._on_token, history=True)

    def _on_token(self, sample: Any) -> None:
        key = str(sample.key_expr)
        appeared = sample.kind == zenoh.SampleKind.PUT
        self._apply(key, appeared)

    def _apply(self, key: str, appeared: bool) -> None:
        try:
            info = parse_token(key)
        except (ValueError, KeyError) as exc:
            log.debug("ignoring graph token %r: %s", key, exc)
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

    def refresh(self, timeout: float = 1.0) -> None:
        """Ask the network for every live token now (a late start need not wait for history)."""
        replies = self._session.liveliness().get(f"{GRAPH_PREFIX}/**", timeout=timeout)
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

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass


class GraphMixin:
    """Node methods about the graph (rclpy's names); they see every process on the network."""

    def _init_graph(self: Any) -> None:
        self.zid = str(self.session.info.zid())
        self.graph = GraphCache(self.session)
        self.graph.listeners.append(self._on_graph_change)
        self._node_token = self.session.liveliness().declare_token(
            node_token_key(self.zid, self.namespace, self.name))

    def _declare_endpoint_token(self: Any, kind: str, entity: Any) -> Any:
        key = endpoint_token_key(kind, self.zid, entity.gid, self.namespace, self.name, entity.key,
                                 entity.msg_type._type_name, entity.msg_type._type_hash, entity.qos)
        return self.session.liveliness().declare_token(key)

    def _on_graph_change(self: Any, appeared: bool, info: TopicEndpointInfo) -> None:
        # Zenoh's thread: tell the local entities on that topic; they hand it to the executor.
        with self._lock:
            entities = list(self.subscriptions if info.endpoint_type is EndpointType.PUBLISHER else self.publishers)
        for entity in entities:
            if entity.key == info.key:
                entity.on_peer(appeared, info)

    def _match_existing(self: Any, entity: Any, kind: EndpointType) -> None:
        """A new entity meets the peers already known (later ones arrive as graph changes)."""
        for info in self.graph.endpoints(entity.key, kind):
            entity.on_peer(True, info)

    def refresh_graph(self: Any, timeout: float = 1.0) -> None:
        """Query the network for the whole graph now (CLI tools call this before answering)."""
        self.graph.refresh(timeout)

    # -- rclpy's graph API ------------------------------------------------------------
    def get_node_names(self: Any) -> list[str]:
        return sorted({n.name for n in self.graph.nodes()})

    def get_node_names_and_namespaces(self: Any) -> list[tuple[str, str]]:
        return sorted({(n.name, n.namespace) for n in self.graph.nodes()})

    def get_topic_names_and_types(self: Any) -> list[tuple[str, list[str]]]:
        topics: dict[str, set[str]] = {}
        for e in self.graph.endpoints():
            topics.setdefault(e.topic_name, set()).add(e.topic_type)
        return [(name, sorted(types)) for name, types in sorted(topics.items())]

    def get_publishers_info_by_topic(self: Any, topic: str) -> list[TopicEndpointInfo]:
        return self.graph.endpoints(self.resolve_topic_name(topic), EndpointType.PUBLISHER)

    def get_subscriptions_info_by_topic(self: Any, topic: str) -> list[TopicEndpointInfo]:
        return self.graph.endpoints(self.resolve_topic_name(topic), EndpointType.SUBSCRIPTION)

    def count_publishers(self: Any, topic: str) -> int:
        return len(self.get_publishers_info_by_topic(topic))

    def count_subscribers(self: Any, topic: str) -> int:
        return len(self.get_subscriptions_info_by_topic(topic))

    def _close_graph(self: Any) -> None:
        graph = getattr(self, "graph", None)
        if graph is not None:
            graph.close()
        token = getattr(self, "_node_token", None)
        if token is not None:
            try:
                token.undeclare()
            except Exception:
                pass
