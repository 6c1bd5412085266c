"""Whole-run metrics of one stream: delivered %, age percentiles, periods, longest gap.

Topic statistics (ROS 2's) are windowed averages for a live view; an experiment or a
demo summary needs the whole distribution (p99), which samples were never seen
(delivered = unique sequence numbers received / sent) and the longest silence.
Memory is bounded: ages and arrivals are kept for at most ``max_samples`` samples.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np


@dataclass
class StreamSummary:
    received: int                 # callbacks, duplicates excluded
    unique: int                   # distinct sequence numbers
    sent: int | None              # as the publisher reported it, if known
    delivered_pct: float          # unique / sent * 100 (NaN without `sent`)
    age_avg_ms: float
    age_p50_ms: float
    age_p99_ms: float
    age_max_ms: float
    period_avg_ms: float
    period_max_ms: float
    longest_gap_ms: float         # the longest time with nothing new, including to the end
    rate_hz: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class StreamRecorder:
    """Feed ``record(seq, source_stamp_ns)`` from a callback; ``summary()`` at any time."""

    def __init__(self, max_samples: int = 200_000) -> None:
        self.max_samples = max_samples
        self._lock = threading.Lock()
        self._ages: list[float] = []
        self._arrivals: list[float] = []
        self._seqs: set[int] = set()
        self._start = time.monotonic()
        self._received = 0

    def reset(self) -> None:
        with self._lock:
            self._ages.clear()
            self._arrivals.clear()
            self._seqs.clear()
            self._received = 0
            self._start = time.monotonic()

    def record(self, seq: int, source_stamp_ns: int, now_ns: int | None = None) -> None:
        now_ns = now_ns or time.time_ns()
        with self._lock:
            self._received += 1
            if len(self._seqs) < self.max_samples:
                self._seqs.add(seq)
            if len(self._ages) < self.max_samples:
                self._ages.append((now_ns - source_stamp_ns) / 1e6 if source_stamp_ns else math.nan)
                self._arrivals.append(time.monotonic())

    def lost_pct(self) -> float:
        """Share of the sequence range seen so far that never arrived (NaN before 2 samples)."""
        with self._lock:
            if len(self._seqs) < 2:
                return math.nan
            span = max(self._seqs) - min(self._seqs) + 1
            return 100.0 * (1 - len(self._seqs) / span)

    def summary(self, sent: int | None = None, end: float | None = None) -> StreamSummary:
        with self._lock:
            ages = np.array(self._ages, dtype=float)
            arrivals = np.array(self._arrivals, dtype=float)
            unique = len(self._seqs)
            received = self._received
            start = self._start
        end = end if end is not None else time.monotonic()
        nan = math.nan
        valid = ages[~np.isnan(ages)] if ages.size else ages
        periods = np.diff(arrivals) * 1000 if arrivals.size > 1 else np.array([])
        edges = np.concatenate([[start], arrivals, [end]]) if arrivals.size else np.array([start, end])
        longest_gap = float(np.max(np.diff(edges))) * 1000
        duration = max(end - start, 1e-9)

        def stat(arr: np.ndarray, fn: Any) -> float:
            return float(fn(arr)) if arr.size else nan

        return StreamSummary(
            received=received, unique=unique, sent=sent,
            delivered_pct=(100.0 * unique / sent) if sent else nan,
            age_avg_ms=stat(valid, np.mean), age_p50_ms=stat(valid, lambda a: np.percentile(a, 50)),
            age_p99_ms=stat(valid, lambda a: np.percentile(a, 99)), age_max_ms=stat(valid, np.max),
            period_avg_ms=stat(periods, np.mean), period_max_ms=stat(periods, np.max),
            longest_gap_ms=longest_gap, rate_hz=received / duration,
        )
