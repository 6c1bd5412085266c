"""Rate-limited logging: what a peer can trigger at will must not be able to flood the log.

Every log line caused by received data (a malformed sample, a type mismatch, a failing
callback or request) goes through one :class:`RateLimitedLog`: at most ``burst`` lines per
``interval`` seconds for each key, then silence; the first line after the silence says how
many were suppressed. Keys are kinds of failure (``"malformed"``, ``"callback"``), never a
value a peer chooses (a publisher id would make the table as large as the attacker wants);
the table is bounded anyway.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass


@dataclass(slots=True)
class _Window:
    start: float
    lines: int = 0
    suppressed: int = 0


class RateLimitedLog:
    """``log(key, level, msg, *args, exc_info=False)``: logs unless ``key`` spent its budget."""

    MAX_KEYS = 256

    def __init__(self, logger: logging.Logger, burst: int = 5, interval: float = 10.0) -> None:
        if burst < 1 or not interval > 0:
            raise ValueError("RateLimitedLog needs burst >= 1 and interval > 0")
        self.logger = logger
        self.burst = burst
        self.interval = interval
        self.suppressed_total = 0
        self._windows: OrderedDict[str, _Window] = OrderedDict()
        self._lock = threading.Lock()

    def log(self, key: str, level: int, msg: str, *args: object, exc_info: bool = False) -> bool:
        """Log (True) or count as suppressed (False)."""
        now = time.monotonic()
        with self._lock:
            w = self._windows.get(key)
            if w is None:
                w = self._windows[key] = _Window(now)
                if len(self._windows) > self.MAX_KEYS:
                    self._windows.popitem(last=False)
            else:
                self._windows.move_to_end(key)
            suppressed = 0
            if now - w.start >= self.interval:
                suppressed, w.start, w.lines, w.suppressed = w.suppressed, now, 0, 0
            if w.lines >= self.burst:
                w.suppressed += 1
                self.suppressed_total += 1
                return False
            w.lines += 1
        if suppressed:
            msg = f"{msg} [{suppressed} similar message(s) suppressed in the last {self.interval:g} s]"
        if not self.logger.isEnabledFor(level):
            return True
        self.logger.log(level, msg, *args, exc_info=exc_info)
        return True

    def warning(self, key: str, msg: str, *args: object, exc_info: bool = False) -> bool:
        return self.log(key, logging.WARNING, msg, *args, exc_info=exc_info)

    def error(self, key: str, msg: str, *args: object, exc_info: bool = False) -> bool:
        return self.log(key, logging.ERROR, msg, *args, exc_info=exc_info)
