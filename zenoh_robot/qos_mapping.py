"""How a QoSProfile becomes Zenoh publisher options (the table in docs/architecture.md)."""
from __future__ import annotations

from typing import Any

import zenoh
import zenoh.ext

from .qos import KEEP_ALL_LIMIT, DurabilityPolicy, HistoryPolicy, Priority, QoSProfile, ReliabilityPolicy

_PRIORITY = {p: getattr(zenoh.Priority, p.name) for p in Priority}


def publisher_options(qos: QoSProfile) -> dict[str, Any]:
    """Keyword arguments for ``Session.declare_publisher``.

    BEST_EFFORT samples are routed by Zenoh onto a best-effort (UDP) link when the
    session holds one (``max_links`` >= 2 and a ``udp/`` endpoint); RELIABLE ones onto
    TCP/QUIC. A RELIABLE or KEEP_ALL sample blocks the publisher while Zenoh's queue is full
    instead of being lost; only BEST_EFFORT KEEP_LAST drops (fresh data beats old data).
    RELIABLE KEEP_LAST used to map to DROP: Zenoh's queue is 2 batches per priority and DROP
    waits 1 ms for room, so a reliable publisher threw samples away at the sender whenever
    TCP slowed (12 % at 10 % loss), which no DDS reliable writer does (docs/lossy-link.md).
    KEEP_LAST's depth bounds the subscriber's queue, not what the sender may discard.
    """
    return {
        "reliability": zenoh.Reliability.BEST_EFFORT if qos.reliability is ReliabilityPolicy.BEST_EFFORT
        else zenoh.Reliability.RELIABLE,
        "congestion_control": zenoh.CongestionControl.BLOCK
        if qos.history is HistoryPolicy.KEEP_ALL or qos.reliability is ReliabilityPolicy.RELIABLE
        else zenoh.CongestionControl.DROP,
        "priority": _PRIORITY[qos.priority],
        "express": qos.express,
    }


def _history_limit(qos: QoSProfile) -> int:
    return KEEP_ALL_LIMIT if qos.history is HistoryPolicy.KEEP_ALL else qos.depth


def declare_publisher(session: zenoh.Session, key: str, qos: QoSProfile) -> Any:
    """A plain Zenoh publisher, or for TRANSIENT_LOCAL an advanced one whose cache serves late joiners."""
    if qos.durability is DurabilityPolicy.TRANSIENT_LOCAL:
        return zenoh.ext.declare_advanced_publisher(
            session, key, cache=zenoh.ext.CacheConfig(_history_limit(qos)), publisher_detection=True,
            # Sequence numbers, not timestamps: no need for timestamping in every session config.
            # The stubs make heartbeat/sporadic_heartbeat required; Zenoh defaults both (no heartbeat).
            sample_miss_detection=zenoh.ext.MissDetectionConfig(),  # type: ignore[call-arg]
            **publisher_options(qos))
    return session.declare_publisher(key, **publisher_options(qos))


def declare_subscriber(session: zenoh.Session, key: str, qos: QoSProfile, callback: Any) -> Any:
    """TRANSIENT_LOCAL asks every transient-local publisher, present or late, for its kept samples."""
    if qos.durability is DurabilityPolicy.TRANSIENT_LOCAL:
        history = zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=_history_limit(qos))
        return zenoh.ext.declare_advanced_subscriber(session, key, callback, history=history)
    return session.declare_subscriber(key, callback)
