"""Bounded, rate-limited reporting of repeated refusals.

A peer streaming refused setpoints at 50 Hz must not turn into 50 events and 50 log lines
a second: each (kind, client, reason) key reports its first occurrence at once and then at
most once per ``interval_s``, with the running count. Keys are bounded (ids can be forged).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass


@dataclass
class _Key:
    count: int = 0
    last_report: float = -1e9


class RateLimiter:
    MAX_KEYS = 256

    def __init__(self, interval_s: float = 2.0) -> None:
        self.interval_s = interval_s
        self._keys: dict[tuple[str, ...], _Key] = {}
        self._lock = threading.Lock()
        self.overflow = 0    # occurrences whose key found no room (counted, never reported)

    def hit(self, *key: str) -> int:
        """Count one occurrence; returns the running count when it is time to report, else 0."""
        now = time.monotonic()
        with self._lock:
            k = self._keys.get(key)
            if k is None:
                if len(self._keys) >= self.MAX_KEYS:
                    self.overflow += 1
                    return 0
                k = self._keys[key] = _Key()
            k.count += 1
            if now - k.last_report < self.interval_s:
                return 0
            k.last_report = now
            return k.count

