"""Rate limiting of reports: what a peer can trigger at will must not be able to flood a log or a topic.

One mechanism, :class:`RateLimiter`: each key may report at most ``burst`` times per ``interval``
seconds, then stays silent until its window ends; every occurrence is counted. The table of keys
is bounded: when it is full, windows that ended with nothing suppressed are dropped (their key's
next window would grant the same budget), and a new key that still finds no room is refused
(counted in ``overflow``), never let in by evicting a live window, because keys may carry ids a
peer forges and such an eviction would hand each forged id a fresh budget. :class:`RateLimitedLog`
is that limiter in front of a logger: the first line after a silence says how many were suppressed.
Library keys are kinds of failure (``"malformed"``, ``"callback"``); applications may key by client
id, bounded as above.

Thread safe: both classes are called from Zenoh-fed executors and from worker threads at once.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass


@dataclass(slots=True)
class Admitted:
    """A report that may go out: ``count`` occurrences of the key so far, ``suppressed`` since the last report."""

    count: int
    suppressed: int


@dataclass(slots=True)
class _Window:
    start: float
    lines: int = 0
    suppressed: int = 0
    count: int = 0


class RateLimiter:
    """At most ``burst`` reports per ``interval`` seconds for each key; the first occurrence reports at once."""

    MAX_KEYS = 256

    def __init__(self, burst: int = 1, interval: float = 2.0) -> None:
        if burst < 1 or not interval > 0:
            raise ValueError(f"{type(self).__name__} needs burst >= 1 and interval > 0")
        self.burst = burst
        self.interval = interval
        self.suppressed_total = 0
        self.overflow = 0    # occurrences whose key found no room (counted, never reported)
        self._windows: dict[tuple[str, ...], _Window] = {}
        self._lock = threading.Lock()
        self._swept = float("-inf")

    def admit(self, *key: str) -> Admitted | None:
        """Count one occurrence of ``key``; an :class:`Admitted` if it may be reported, else None."""
        now = time.monotonic()
        with self._lock:
            w = self._windows.get(key)
            if w is None:
                if len(self._windows) >= self.MAX_KEYS and not self._sweep(now):
                    self.overflow += 1
                    return None
                w = self._windows[key] = _Window(now)
            w.count += 1
            suppressed = 0
            if now - w.start >= self.interval:
                suppressed, w.start, w.lines, w.suppressed = w.suppressed, now, 0, 0
            if w.lines >= self.burst:
                w.suppressed += 1
                self.suppressed_total += 1
                return None
            w.lines += 1
            return Admitted(w.count, suppressed)

    def _sweep(self, now: float) -> bool:
        """Under the lock, with the table full: drop the windows that ended with nothing left to say.
        A key dropped so comes back with the budget its next window would have given it anyway, so a
        forger gains nothing; a flood of live keys is swept at most four times per interval."""
        if now - self._swept < self.interval / 4:
            return False
        self._swept = now
        done = [k for k, w in self._windows.items() if now - w.start >= self.interval and not w.suppressed]
        for k in done:
            del self._windows[k]
        return bool(done)

    def hit(self, *key: str) -> int:
        """Count one occurrence; the key's running count when it may be reported, else 0."""
        admitted = self.admit(*key)
        return admitted.count if admitted else 0


class RateLimitedLog:
    """``log(key, level, msg, *args, exc_info=False)``: logs unless ``key`` spent its budget."""

    def __init__(self, logger: logging.Logger, burst: int = 5, interval: float = 10.0) -> None:
        self.logger = logger
        self._limiter = RateLimiter(burst, interval)

    @property
    def interval(self) -> float:
        return self._limiter.interval

    @property
    def suppressed_total(self) -> int:
        return self._limiter.suppressed_total

    def log(self, key: str, level: int, msg: str, *args: object, exc_info: bool = False) -> bool:
        """Log (True) or count as suppressed (False)."""
        admitted = self._limiter.admit(key)
        if admitted is None:
            return False
        if admitted.suppressed:
            msg = f"{msg} [{admitted.suppressed} similar message(s) suppressed in the last {self.interval:g} s]"
        if not self.logger.isEnabledFor(level):
            return True
        self.logger.log(level, msg, *args, exc_info=exc_info)
        return True

    def warning(self, key: str, msg: str, *args: object, exc_info: bool = False) -> bool:
        return self.log(key, logging.WARNING, msg, *args, exc_info=exc_info)

    def error(self, key: str, msg: str, *args: object, exc_info: bool = False) -> bool:
        return self.log(key, logging.ERROR, msg, *args, exc_info=exc_info)

    def exception(self, key: str, msg: str, *args: object) -> bool:
        """``error`` with the current exception's traceback."""
        return self.log(key, logging.ERROR, msg, *args, exc_info=True)
