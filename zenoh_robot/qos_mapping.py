"""How a QoSProfile becomes Zenoh publisher options (DESIGN.md's table)."""
from __future__ import annotations

from typing import Any

import zenoh

from .qos import HistoryPolicy, Priority, QoSProfile, ReliabilityPolicy

_PRIORITY = {p: getattr(zenoh.Priority, p.name) for p in Priority}


def publisher_options(qos: QoSProfile) -> dict[str, Any]:
    """Keyword arguments for ``Session.declare_publisher``.

    BEST_EFFORT samples are routed by Zenoh onto a best-effort (UDP) link when the
    session holds one (``max_links`` >= 2 and a ``udp/`` endpoint); RELIABLE ones onto
    TCP/QUIC. KEEP_LAST drops under congestion (fresh data beats old data); KEEP_ALL
    blocks the publisher instead of losing a sample.
    """
    return {
        "reliability": zenoh.Reliability.BEST_EFFORT if qos.reliability is ReliabilityPolicy.BEST_EFFORT
        else zenoh.Reliability.RELIABLE,
        "congestion_control": zenoh.CongestionControl.BLOCK if qos.history is HistoryPolicy.KEEP_ALL
        else zenoh.CongestionControl.DROP,
        "priority": _PRIORITY[qos.priority],
        "express": qos.express,
    }
