"""Redundancy for lossy links: each sample also carries the last k samples of its publisher.

On a best-effort link a lost packet is gone; if the next packet carries the lost
sample too, the subscriber recovers it with no round trip and no waiting (unlike
reliable retransmission, whose queue makes everything behind a loss old). The
subscriber delivers in sequence order and drops what it has already delivered.
"""
from __future__ import annotations

from collections import deque
from typing import Any

HISTORY_KEY = "r"   # envelope.extra key: [[seq, stamp_ns, body], ...], oldest first
REPEAT_KEY = "n"    # envelope.extra key: how many delayed copies of this packet follow


class RedundantHistory:
    """Publisher side: the last ``k`` (seq, stamp, body) sent, to attach to the next sample."""

    def __init__(self, k: int) -> None:
        if k < 1:
            raise ValueError("redundancy needs k >= 1")
        self._past: deque[list[Any]] = deque(maxlen=k)

    def extra(self) -> dict[str, Any] | None:
        return {HISTORY_KEY: list(self._past)} if self._past else None

    def record(self, seq: int, stamp_ns: int, body: Any) -> None:
        self._past.append([seq, stamp_ns, body])


class Deduplicator:
    """Subscriber side, one per subscription: what each publisher has had delivered.

    ``fresh(pub_id, seq, stamp, body, extra)`` returns the samples to deliver, oldest
    first: recovered ones from the carried history, then this one; duplicates (repeats
    of a packet, or history already delivered) yield nothing.
    """

    MAX_PUBLISHERS = 1024   # bounded: forget the least recently seen publisher beyond this

    def __init__(self) -> None:
        self._last: dict[int, int] = {}
        self.duplicates = 0
        self.recovered = 0

    def fresh(self, pub_id: int, seq: int, stamp_ns: int, body: Any,
              extra: dict[str, Any]) -> list[tuple[int, int, Any]]:
        last = self._last.get(pub_id)
        if last is not None and seq <= last:
            if seq < last - 1000:      # far behind: the publisher restarted its sequence
                last = None
            else:
                self.duplicates += 1
                return []
        out: list[tuple[int, int, Any]] = []
        history = extra.get(HISTORY_KEY)
        if isinstance(history, list) and last is not None:
            for item in history:
                if (isinstance(item, list) and len(item) == 3 and isinstance(item[0], int)
                        and last < item[0] < seq and isinstance(item[1], int)):
                    out.append((item[0], item[1], item[2]))
            out.sort(key=lambda t: t[0])
            self.recovered += len(out)
        out.append((seq, stamp_ns, body))
        if pub_id not in self._last and len(self._last) >= self.MAX_PUBLISHERS:
            self._last.pop(next(iter(self._last)))
        self._last.pop(pub_id, None)
        self._last[pub_id] = seq
        return out
