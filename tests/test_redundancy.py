"""Redundant history and in-order deduplication (the resilient profile's recovery)."""
from __future__ import annotations

import random

from zenoh_robot._wire.redundancy import Deduplicator, RedundantHistory


def _send(n: int, k: int):
    hist = RedundantHistory(k)
    for seq in range(1, n + 1):
        extra = hist.extra() or {}
        yield seq, seq * 1000, f"body{seq}", extra
        hist.record(seq, seq * 1000, f"body{seq}")


def test_recovers_every_sample_when_gaps_are_shorter_than_k() -> None:
    rng = random.Random(7)
    dedup = Deduplicator()
    delivered = []
    lost_run = 0
    for seq, stamp, body, extra in _send(2000, k=5):
        # Lose 40% of packets, but never more than 4 in a row.
        if lost_run < 4 and rng.random() < 0.4 and seq not in (1, 2000):
            lost_run += 1
            continue
        lost_run = 0
        for copy in range(2):        # each packet repeated: the copy must be dropped
            delivered += [s for s, _, _ in dedup.fresh(42, seq, stamp, body, extra)]
    assert delivered == list(range(1, 2001))
    assert dedup.recovered > 0 and dedup.duplicates >= 2000 - dedup.recovered - 1


def test_gap_longer_than_history_is_lost_not_reordered() -> None:
    dedup = Deduplicator()
    out = []
    for seq, stamp, body, extra in _send(20, k=2):
        if 5 <= seq <= 9:
            continue
        out += [s for s, _, _ in dedup.fresh(1, seq, stamp, body, extra)]
    assert out == [1, 2, 3, 4, 8, 9, 10] + list(range(11, 21))   # 5-7 gone for good, order kept


def test_publishers_are_independent_and_a_restart_is_accepted() -> None:
    dedup = Deduplicator()
    assert [s for s, _, _ in dedup.fresh(1, 5000, 0, "a", {})] == [5000]
    assert [s for s, _, _ in dedup.fresh(2, 1, 0, "b", {})] == [1]
    assert dedup.fresh(1, 4999, 0, "a", {}) == []          # late duplicate
    assert [s for s, _, _ in dedup.fresh(1, 1, 0, "a", {})] == [1]   # publisher restarted from 1


def test_garbage_history_is_ignored() -> None:
    dedup = Deduplicator()
    dedup.fresh(1, 1, 0, "a", {})
    out = dedup.fresh(1, 3, 0, "c", {"r": [["x"], [2, "notint", "b"], 7, None]})
    assert [s for s, _, _ in out] == [3]
