"""Whole-run metrics of one stream: delivered %, age percentiles, periods, longest gap.

Topic statistics (ROS 2's) are windowed averages for a live view; an experiment or a
demo summary needs the whole distribution (p99), which samples were never seen
(delivered = unique sequence numbers received / sent) and the longest silence. A
``StreamRecorder`` keeps the raw (seq, source stamp, arrival) of every sample, bounded
by ``max_samples``, so a run can be summarised live or dumped and analysed later
against the sender's own record over an exact time window.
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
    received: int                 # samples, duplicates included
    unique: int                   # distinct sequence numbers
    sent: int | None              # as the sender recorded it, if known
    delivered_pct: float          # unique / sent * 100 (NaN without `sent`)
    age_avg_ms: float
    age_p50_ms: float
    age_p99_ms: float
    age_max_ms: float
    period_avg_ms: float
    period_max_ms: float
    longest_gap_ms: float         # the longest time with nothing new, window edges included
    rate_hz: float                # unique samples per second over the window
    gap_p99_ms: float = math.nan  # 99th percentile of the times with nothing new (edges included)
    gaps_over_500ms: int = 0      # how often nothing new came for over 500 ms (PX4's OFFBOARD limit)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class StreamRecorder:
    """Feed ``record(seq, source_stamp_ns)`` from a callback (or a sender); summarise any time."""

    def __init__(self, max_samples: int = 500_000) -> None:
        self.max_samples = max_samples
        self._lock = threading.Lock()
        self._seq: list[int] = []
        self._stamp: list[int] = []
        self._arrival: list[int] = []
        self._start_ns = time.time_ns()
        self.overflow = 0

    def record(self, seq: int, source_stamp_ns: int, now_ns: int | None = None) -> None:
        now_ns = now_ns or time.time_ns()
        with self._lock:
            if len(self._seq) >= self.max_samples:
                self.overflow += 1
                return
            self._seq.append(seq)
            self._stamp.append(source_stamp_ns)
            self._arrival.append(now_ns)

    def __len__(self) -> int:
        return len(self._seq)

    def to_dict(self) -> dict[str, Any]:
        with self._lock:
            return {"seq": list(self._seq), "stamp_ns": list(self._stamp), "arrival_ns": list(self._arrival),
                    "start_ns": self._start_ns, "overflow": self.overflow}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "StreamRecorder":
        rec = cls()
        rec._seq, rec._stamp, rec._arrival = list(data["seq"]), list(data["stamp_ns"]), list(data["arrival_ns"])
        rec._start_ns = int(data.get("start_ns", rec._start_ns))
        rec.overflow = int(data.get("overflow", 0))
        return rec

    def lost_pct(self) -> float:
        """Share of the sequence range seen so far that never arrived (NaN before 2 samples)."""
        with self._lock:
            seqs = set(self._seq)
        if len(seqs) < 2:
            return math.nan
        return 100.0 * (1 - len(seqs) / (max(seqs) - min(seqs) + 1))

    def summary(self, sent: int | None = None) -> StreamSummary:
        """Everything recorded so far, from creation to now."""
        with self._lock:
            start = self._start_ns
        return analyse(self, None, start, time.time_ns(), sent=sent)


def analyse(received: StreamRecorder, sent_by: StreamRecorder | None, t0_ns: int, t1_ns: int,
            sent: int | None = None) -> StreamSummary:
    """Figures over the window [t0, t1] (ns since the epoch).

    With the sender's record, what counts is the samples it sent in the window (by source
    stamp) and which of those arrived at all (whenever they arrived); without it, the
    samples that arrived in the window.
    """
    with received._lock:
        seq = np.array(received._seq, dtype=np.int64)
        stamp = np.array(received._stamp, dtype=np.int64)
        arrival = np.array(received._arrival, dtype=np.int64)
    if sent_by is not None:
        with sent_by._lock:
            s_seq = np.array(sent_by._seq, dtype=np.int64)
            s_stamp = np.array(sent_by._stamp, dtype=np.int64)
        wanted = s_seq[(s_stamp >= t0_ns) & (s_stamp <= t1_ns)]
        sent = int(np.unique(wanted).size)
        keep = np.isin(seq, wanted)
    else:
        keep = (arrival >= t0_ns) & (arrival <= t1_ns)
    seq, stamp, arrival = seq[keep], stamp[keep], arrival[keep]
    # First arrival of each sequence number: repeats and redundant copies count once.
    order = np.argsort(arrival, kind="stable")
    seq, stamp, arrival = seq[order], stamp[order], arrival[order]
    _, first = np.unique(seq, return_index=True)
    first.sort()
    u_stamp, u_arrival = stamp[first], arrival[first]
    ages = (u_arrival - u_stamp)[u_stamp > 0] / 1e6
    in_window = u_arrival[(u_arrival >= t0_ns) & (u_arrival <= t1_ns)]
    periods = np.diff(in_window) / 1e6
    edges = np.concatenate([[t0_ns], in_window, [t1_ns]])
    duration = max((t1_ns - t0_ns) / 1e9, 1e-9)
    nan = math.nan

    def stat(a: np.ndarray, fn: Any) -> float:
        return float(fn(a)) if a.size else nan

    unique = int(first.size)
    return StreamSummary(
        received=int(seq.size), unique=unique, sent=sent,
        delivered_pct=(100.0 * unique / sent) if sent else nan,
        age_avg_ms=stat(ages, np.mean), age_p50_ms=stat(ages, lambda a: np.percentile(a, 50)),
        age_p99_ms=stat(ages, lambda a: np.percentile(a, 99)), age_max_ms=stat(ages, np.max),
        period_avg_ms=stat(periods, np.mean), period_max_ms=stat(periods, np.max),
        longest_gap_ms=float(np.max(np.diff(edges))) / 1e6, rate_hz=in_window.size / duration,
        gap_p99_ms=float(np.percentile(np.diff(edges), 99)) / 1e6,
        gaps_over_500ms=int(np.count_nonzero(np.diff(edges) > 500e6)),
    )
