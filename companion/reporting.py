"""Bounded, rate-limited reporting of repeated refusals, and the delivered sensor rate.

A peer streaming refused setpoints at 50 Hz must not turn into 50 events and 50 log lines
a second: each (kind, client, reason) key reports its first occurrence at once and then at
most once per ``interval_s``, with the running count. Keys are bounded (ids can be forged).
"""
from __future__ import annotations

import threading
import time
from collections import deque
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


class RateMeter:
    """Samples per second over a sliding window of arrival times (bounded)."""

    def __init__(self, window_s: float = 2.0, max_samples: int = 4096) -> None:
        self.window_s = window_s
        self._t: deque[float] = deque(maxlen=max_samples)
        self._lock = threading.Lock()
        self._started = time.monotonic()

    def tick(self, now: float | None = None) -> None:
        with self._lock:
            self._t.append(time.monotonic() if now is None else now)

    def reset(self) -> None:
        with self._lock:
            self._t.clear()
            self._started = time.monotonic()

    def rate_hz(self, now: float | None = None) -> float:
        """NaN until a full window has been watched; 0.0 when nothing arrived in it."""
        now = time.monotonic() if now is None else now
        with self._lock:
            if now - self._started < self.window_s:
                return float("nan")
            while self._t and now - self._t[0] > self.window_s:
                self._t.popleft()
            n = len(self._t)
            if n < 2:
                return 0.0
            span = max(now - self._t[0], self._t[-1] - self._t[0])
            # A full deque undercounts: its span is what the window really covers.
            return (n - 1) / span if len(self._t) == self._t.maxlen else n / self.window_s
