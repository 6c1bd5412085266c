"""Delayed copies of a sample, so each copy leaves in its own datagram.

Zenoh batches messages written within ~1 ms into one datagram; copies sent back to
back would share a packet and be lost together, which defeats the point of sending
them. One thread per node re-sends each payload ``copies`` times, ``interval`` apart.

Deadline-driven copies (:meth:`Repeater.schedule_latest`): what a stream with a deadline
needs is that *some* packet arrives within every deadline window, not that each sample
arrives 4 times within 10 ms. So the newest payload of a publisher is re-sent ``copies``
times spread evenly over ``window`` (a fraction of the deadline); a newer payload replaces
the pending copies of the older one (it carries the older samples in its redundancy
history, and an old copy delivered after a newer sample would only be stale). Under
independent loss p, a gap longer than the window needs every one of the ~``copies``
packets in it lost: p ** copies (0.9 ** 64 = 1e-3 at 90 % loss).

That bound assumes each copy leaves when it is due. A thread starved of the CPU sends its
late copies back to back, in one datagram, and the window they were spread over is lost
with them; :meth:`Repeater.stats` counts the copies that left more than ``LATE_S`` after
their time (and the worst lateness), so a flight's record tells a starved repeater from a
lossy link.
"""
from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger("zenoh_robot.repeater")

# Not a multiple of common stream periods (5, 10, 33 ms): a copy must not share a batch with
# the next original sample of a 200 Hz stream.
REPEAT_INTERVAL_S = 0.003
# Late enough that the copy may share a datagram with the next ones (several intervals).
LATE_S = 0.02


class Repeater:
    def __init__(self, max_pending: int = 4096) -> None:
        self.max_pending = max_pending
        self._heap: list[tuple[float, int, Callable[[bytes], None], bytes, tuple[int, int] | None]] = []
        self._generation: dict[int, int] = {}   # key -> generation of its live schedule_latest copies
        self._cond = threading.Condition()
        self._count = itertools.count()
        self._closed = False
        self.dropped = 0
        self.sent = 0             # copies handed to Zenoh
        self.late = 0             # ... of them more than LATE_S after their time
        self.max_late_s = 0.0
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
                heapq.heappush(self._heap, (now + i * interval, next(self._count), put, payload, None))
            self._cond.notify()

    def schedule_latest(self, key: int, put: Callable[[bytes], None], payload: bytes, copies: int,
                        window: float) -> None:
        """Re-send ``payload`` ``copies`` times evenly over ``window`` s, cancelling ``key``'s older copies."""
        now = time.monotonic()
        step = max(window / max(copies, 1), REPEAT_INTERVAL_S)
        with self._cond:
            gen = self._generation.get(key, 0) + 1
            self._generation[key] = gen
            if len(self._generation) > self.max_pending:   # bounded: forget the oldest keys
                del self._generation[next(iter(self._generation))]
            for i in range(1, copies + 1):
                if len(self._heap) >= self.max_pending:
                    self.dropped += 1
                    continue
                heapq.heappush(self._heap, (now + i * step, next(self._count), put, payload, (key, gen)))
            self._cond.notify()

    def cancel(self, key: int) -> None:
        """Drop ``key``'s pending schedule_latest copies (its publisher is going away)."""
        with self._cond:
            self._generation.pop(key, None)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._heap or self._heap[0][0] > time.monotonic()):
                    timeout = self._heap[0][0] - time.monotonic() if self._heap else None
                    self._cond.wait(timeout)
                if self._closed:
                    return
                due, _, put, payload, tag = heapq.heappop(self._heap)
                if tag is not None and self._generation.get(tag[0]) != tag[1]:
                    continue     # superseded by a newer payload of the same publisher
                late = time.monotonic() - due
                self.sent += 1
                if late > LATE_S:
                    self.late += 1
                self.max_late_s = max(self.max_late_s, late)
            try:
                put(payload)
            except Exception as exc:   # the publisher closed meanwhile: nothing to repeat to
                log.debug("repeat dropped: %s", exc)

    def stats(self) -> dict[str, float]:
        """Copies sent, late (more than LATE_S after their time), the worst lateness, and dropped."""
        with self._cond:
            return {"sent": self.sent, "late": self.late, "max_late_ms": round(self.max_late_s * 1000, 1),
                    "dropped": self.dropped}

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._heap.clear()
            self._generation.clear()
            self._cond.notify()
        self._thread.join(timeout=1.0)
