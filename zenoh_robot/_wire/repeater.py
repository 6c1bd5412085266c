"""Delayed copies of a sample, so each copy leaves in its own datagram.

Zenoh batches messages written within ~1 ms into one datagram; copies sent back to
back would share a packet and be lost together, which defeats the point of sending
them. One thread per node re-sends each payload ``copies`` times, ``interval`` apart.
"""
from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger("zenoh_robot._wire.repeater")

# Not a multiple of common stream periods (5, 10, 33 ms): a copy must not share a batch with
# the next original sample of a 200 Hz stream.
REPEAT_INTERVAL_S = 0.003


class Repeater:
    def __init__(self, max_pending: int = 4096) -> None:
        self.max_pending = max_pending
        self._heap: list[tuple[float, int, Callable[[bytes], None], bytes]] = []
        self._cond = threading.Condition()
        self._count = itertools.count()
        self._closed = False
        self.dropped = 0
        self._thread = threading.Thread(target=self._run, name="zr-repeater", daemon=True)
        self._thread.start()

    def schedule(self, put: Callable[[bytes], None], payload: bytes, copies: int,
                 interval: float = REPEAT_INTERVAL_S) -> None:
        now = time.monotonic()
        with self._cond:
            for i in range(1, copies + 1):
                if len(self._heap) >= self.max_pending:   # bounded: a stalled link must not grow us
                    self.dropped += 1
                    continue
                heapq.heappush(self._heap, (now + i * interval, next(self._count), put, payload))
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._heap or self._heap[0][0] > time.monotonic()):
                    timeout = self._heap[0][0] - time.monotonic() if self._heap else None
                    self._cond.wait(timeout)
                if self._closed:
                    return
                _, _, put, payload = heapq.heappop(self._heap)
            try:
                put(payload)
            except Exception as exc:   # the publisher closed meanwhile: nothing to repeat to
                log.debug("repeat dropped: %s", exc)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._heap.clear()
            self._cond.notify()
        self._thread.join(timeout=1.0)
