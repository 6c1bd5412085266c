"""Whole-run stream metrics: delivered %, percentiles, longest gap, windows against the sender."""
from __future__ import annotations

import math
import time

import pytest

from zenoh_robot.tools.stream_metrics import StreamRecorder, analyse

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

MS = 1_000_000


def test_delivered_and_ages() -> None:
    rec = StreamRecorder()
    now = time.time_ns()
    for seq in range(100):
        if seq % 10 == 3:
            continue                                   # 10 lost
        rec.record(seq, now - 5 * MS, now_ns=now)      # 5 ms old
    rec.record(5, now - 5 * MS, now_ns=now + 1)        # a duplicate: counted received, not unique
    s = rec.summary(sent=100)
    assert s.unique == 90 and s.received == 91 and s.delivered_pct == 90.0
    assert abs(s.age_avg_ms - 5.0) < 1e-6 and abs(s.age_p99_ms - 5.0) < 1e-6
    assert abs(rec.lost_pct() - 100 * (1 - 90 / 100)) < 1e-9


def test_empty_stream_is_nan_not_zero() -> None:
    s = StreamRecorder().summary(sent=10)
    assert s.unique == 0 and s.delivered_pct == 0.0
    assert math.isnan(s.age_avg_ms) and math.isnan(s.period_avg_ms)
    assert s.longest_gap_ms >= 0


def test_window_against_the_senders_record() -> None:
    sent, got = StreamRecorder(), StreamRecorder()
    t0 = 1_000_000 * MS
    for seq in range(100):                       # 10 Hz for 10 s
        stamp = t0 + seq * 100 * MS
        sent.record(seq, stamp, stamp)
        if 40 <= seq < 45:
            continue                             # a 600 ms hole
        got.record(seq, stamp, stamp + 20 * MS)  # 20 ms transit
        if seq % 2 == 0:
            got.record(seq, stamp, stamp + 30 * MS)   # redundant copy
    s = analyse(got, sent, t0 + 2000 * MS, t0 + 7000 * MS)   # seqs 20..70
    assert s.sent == 51 and s.unique == 46
    assert abs(s.delivered_pct - 100 * 46 / 51) < 1e-9
    assert abs(s.age_avg_ms - 20.0) < 1e-6          # first copy's age, not the redundant one's
    assert abs(s.longest_gap_ms - 600.0) < 1e-6
    assert abs(s.period_avg_ms - 5000 / 45) < 1.0


def test_dump_and_reload() -> None:
    rec = StreamRecorder()
    rec.record(1, 10, 20)
    back = StreamRecorder.from_dict(rec.to_dict())
    assert back.to_dict() == rec.to_dict()
