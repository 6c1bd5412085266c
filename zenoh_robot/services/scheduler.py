"""The one thread that runs due callbacks (retries, deadlines) for every service client in the process."""
from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger("zenoh_robot.services")    # one logger for the package, whichever module logs


class _Scheduler:
    """One daemon thread running due callbacks (retries, deadlines) for every client in the process."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._cv = threading.Condition()
        self._ids = itertools.count()
        self._thread: threading.Thread | None = None

    def at(self, when: float, fn: Callable[[], None]) -> None:
        with self._cv:
            heapq.heappush(self._heap, (when, next(self._ids), fn))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="zr-service-retries", daemon=True)
                self._thread.start()
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._heap or self._heap[0][0] > time.monotonic():
                    self._cv.wait(None if not self._heap else max(0.0, self._heap[0][0] - time.monotonic()))
                _, _, fn = heapq.heappop(self._heap)
            try:
                fn()
            except Exception as exc:     # a retry must never kill the thread every client shares
                log.debug("service retry callback failed: %s", exc)


_scheduler = _Scheduler()
