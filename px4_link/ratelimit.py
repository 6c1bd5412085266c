"""Logging that an attacker with a UDP socket cannot turn into a disk-filling flood."""
from __future__ import annotations

import logging
import threading
import time


class RateLimitedLogger:
    """At most one record per ``key`` every ``interval`` seconds; the rest are counted and
    reported with the next record that gets through."""

    def __init__(self, logger: logging.Logger, interval: float = 5.0) -> None:
        self._log = logger
        self.interval = interval
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def log(self, level: int, key: str, msg: str, *args: object, exc_info: bool = False) -> None:
        now = time.monotonic()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self.interval:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return
            if len(self._last) > 256:   # keys come from our code, but stay bounded anyway
                self._last.clear()
            self._last[key] = now
            skipped = self._suppressed.pop(key, 0)
        if skipped:
            msg += f" ({skipped} similar suppressed)"
        self._log.log(level, msg, *args, exc_info=exc_info)

    def warning(self, key: str, msg: str, *args: object) -> None:
        self.log(logging.WARNING, key, msg, *args)

    def exception(self, key: str, msg: str, *args: object) -> None:
        self.log(logging.ERROR, key, msg, *args, exc_info=True)
