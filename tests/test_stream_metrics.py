"""Whole-run stream metrics: delivered %, percentiles, longest gap."""
from __future__ import annotations

import math
import time

from zenoh_robot.stream_metrics import StreamRecorder


def test_delivered_and_ages() -> None:
    rec = StreamRecorder()
    now = time.time_ns()
    for seq in range(100):
        if seq % 10 == 3:
            continue                                   # 10 lost
        rec.record(seq, now - 5_000_000, now_ns=now)   # 5 ms old
    rec.record(5, now - 5_000_000, now_ns=now)         # a duplicate: counted received, not unique
    s = rec.summary(sent=100)
    assert s.unique == 90 and s.received == 91 and s.delivered_pct == 90.0
    assert abs(s.age_avg_ms - 5.0) < 1e-6 and abs(s.age_p99_ms - 5.0) < 1e-6


def test_empty_stream_is_nan_not_zero() -> None:
    s = StreamRecorder().summary(sent=10)
    assert s.unique == 0 and s.delivered_pct == 0.0
    assert math.isnan(s.age_avg_ms) and math.isnan(s.period_avg_ms)
    assert s.longest_gap_ms >= 0


def test_longest_gap_includes_silence_to_the_end() -> None:
    rec = StreamRecorder()
    rec.record(1, time.time_ns())
    time.sleep(0.2)
    s = rec.summary()
    assert s.longest_gap_ms >= 150
