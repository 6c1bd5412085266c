"""The bounded hand-off from Zenoh's callback threads to the backend's decode worker.

PX4 sends every uORB update (~880 samples/s on the ground). A Zenoh callback only checks the
topic's delivery interval (a time compare), copies the payload and appends it to that topic's
bounded deque: the oldest sample of a topic is dropped when its deque is full (the newest state is
what matters), and one topic's burst never delays another's. Decoding happens on the worker.
"""
from __future__ import annotations

import threading
import time
from collections import deque

Item = tuple[bytes, float]   # (payload, monotonic receive time)


class TopicQueue:
    """One topic's deque and its delivery interval (``period`` s, 0: every sample; None: off)."""

    __slots__ = ("name", "items", "period", "due", "dropped", "skipped", "received")

    def __init__(self, name: str, depth: int) -> None:
        self.name = name
        self.items: deque[Item] = deque(maxlen=depth)
        self.period: float | None = 0.0
        self.due = 0.0
        self.dropped = 0     # pushed out by newer samples before the worker took them
        self.skipped = 0     # not wanted at the asked interval
        self.received = 0

    def offer(self, now: float) -> bool:
        """Whether a sample arriving ``now`` is wanted (the interval's accumulator, no bursts after a lull)."""
        self.received += 1
        period = self.period
        if period is None:
            self.skipped += 1
            return False
        if period == 0.0:
            return True
        if now < self.due:
            self.skipped += 1
            return False
        self.due = self.due + period if now - self.due < period else now + period
        return True


class Inbox:
    def __init__(self, names: list[str], depth: int = 8) -> None:
        self.queues = {n: TopicQueue(n, depth) for n in names}
        self._wake = threading.Event()

    def put(self, q: TopicQueue, payload: bytes) -> None:
        """Zenoh's thread: append and wake the worker; never blocks."""
        if len(q.items) == q.items.maxlen:
            q.dropped += 1
        q.items.append((payload, time.monotonic()))
        self._wake.set()

    def wait(self, timeout: float) -> None:
        self._wake.wait(timeout)
        self._wake.clear()

    def wake(self) -> None:
        self._wake.set()

    def drain(self) -> list[tuple[str, bytes, float]]:
        """Worker: everything queued, topic by topic, each in arrival order."""
        out: list[tuple[str, bytes, float]] = []
        for q in self.queues.values():
            items = q.items
            while items:
                try:
                    payload, t = items.popleft()
                except IndexError:
                    break
                out.append((q.name, payload, t))
        return out
