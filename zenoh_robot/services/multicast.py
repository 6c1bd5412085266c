"""The put-based request/reply transport of multicast sessions: reply attachments and best-effort publishers.

Zenoh routes no queries over its UDP multicast transport, so there a request is put on
``<service key>/@rq`` and its reply on ``<service key>/@rp/<client_id>`` (the package doc says how).
The attachment of a reply carries the call's seq (8 bytes big-endian) and a byte: 0 = response,
1 = error payload.
"""
from __future__ import annotations

from typing import Any

import zenoh

_REPLY_OK, _REPLY_ERR = 0, 1
MAX_REPLY_PUBLISHERS = 64    # server: best-effort reply publishers kept, one per recent client (LRU)


def _reply_attachment(seq: int, ok: bool) -> bytes:
    return (seq & 0xFFFFFFFFFFFFFFFF).to_bytes(8, "big") + bytes([_REPLY_OK if ok else _REPLY_ERR])


def _parse_reply_attachment(data: bytes | None) -> tuple[int, bool] | None:
    """(seq, ok) of a put-carried reply, or None if the attachment is not ours."""
    if data is None or len(data) != 9 or data[8] not in (_REPLY_OK, _REPLY_ERR):
        return None
    return int.from_bytes(data[:8], "big"), data[8] == _REPLY_OK


def _best_effort_publisher(session: zenoh.Session, key: str) -> Any:
    # Best effort: on a unicast session with a UDP and a TCP link this rides UDP (a lost copy is
    # replaced by the next, never queued behind a TCP retransmission); DROP: never block a caller.
    return session.declare_publisher(key, reliability=zenoh.Reliability.BEST_EFFORT,
                                     congestion_control=zenoh.CongestionControl.DROP,
                                     priority=zenoh.Priority.INTERACTIVE_HIGH)


# A reply on a multicast session goes out in spread copies (zenoh_robot/services/call_plan.py: as many as the
# client asks for, or the server's own loss estimate needs); this many when neither says.
MULTICAST_REPLY_COPIES = 2
