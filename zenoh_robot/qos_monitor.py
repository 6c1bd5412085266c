"""One thread per node for the QoS policies that are about time passing.

Deadlines, liveliness leases and AUTOMATIC liveliness assertions must be checked
whether or not samples arrive and whether or not the user spins, so they cannot
live on the executor. Entities register while they need checking; each ``tick``
only compares clocks and, on a change, hands the event to the executor.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Protocol

log = logging.getLogger("zenoh_robot.qos_monitor")

MIN_PERIOD_S = 0.002
MAX_PERIOD_S = 0.1


class Ticking(Protocol):
    tick_period: float

    def tick(self, now: float) -> None: ...


class QoSMonitor:
    def __init__(self) -> None:
        self._entities: list[Ticking] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closed = False
        self._period = MAX_PERIOD_S
        self._thread = threading.Thread(target=self._run, name="zr-qos-monitor", daemon=True)
        self._thread.start()

    def register(self, entity: Ticking) -> None:
        with self._lock:
            if entity not in self._entities:
                self._entities.append(entity)
            self._period = _period(self._entities)
        self._wake.set()

    def unregister(self, entity: Ticking) -> None:
        with self._lock:
            if entity in self._entities:
                self._entities.remove(entity)
            self._period = _period(self._entities)

    def _run(self) -> None:
        while not self._closed:
            # Nothing registered: nothing to check until register() or close() sets the wake (an idle
            # wake-up costs ~0.15 ms of CPU; executor.py says where that was measured).
            self._wake.wait(self._period if self._entities else None)
            self._wake.clear()
            if self._closed:
                return
            with self._lock:
                entities = list(self._entities)
            now = time.monotonic()
            for entity in entities:
                try:
                    entity.tick(now)
                except Exception:
                    log.exception("QoS check failed for %r", entity)

    def close(self) -> None:
        self._closed = True
        self._wake.set()
        self._thread.join(timeout=1.0)


def _period(entities: list[Ticking]) -> float:
    # A quarter of the shortest deadline or lease: an event is seen at most 25 % late.
    if not entities:
        return MAX_PERIOD_S
    return min(MAX_PERIOD_S, max(MIN_PERIOD_S, min(e.tick_period for e in entities) / 4))
