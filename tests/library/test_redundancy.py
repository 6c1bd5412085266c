"""Redundant history and in-order deduplication (the resilient profile's recovery)."""
from __future__ import annotations

import random
import time

import pytest
from conftest import linked_configs

from zenoh_robot import Node
from zenoh_robot.redundancy import Deduplicator, RedundantHistory

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


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
        for _copy in range(2):        # each packet repeated: the copy must be dropped
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
    # Late but never delivered: delivered now (dropping it is what would let a forged high
    # seq silence a stream); its repeat is a duplicate.
    assert [s for s, _, _ in dedup.fresh(1, 4999, 0, "a", {})] == [4999]
    assert dedup.fresh(1, 4999, 0, "a", {}) == []
    assert dedup.fresh(1, 5000, 0, "a", {}) == []
    assert [s for s, _, _ in dedup.fresh(1, 1, 0, "a", {})] == [1]   # publisher restarted from 1
    assert dedup.fresh(1, 1, 0, "a", {}) == []


def test_garbage_history_is_ignored() -> None:
    dedup = Deduplicator()
    dedup.fresh(1, 1, 0, "a", {})
    out = dedup.fresh(1, 3, 0, "c", {"r": [["x"], [2, "notint", "b"], 7, None]})
    assert [s for s, _, _ in out] == [3]


def _real_stream(dedup: Deduplicator, seqs, pub: int = 9):
    return [s for seq in seqs for s, _, _ in dedup.fresh(pub, seq, seq, f"real{seq}", {})]


def test_a_forged_seq_ahead_costs_the_real_stream_at_most_the_seq_it_took() -> None:
    # Defect 2: one sample with the real publisher's id and seq + 999 used to drop the next 999.
    dedup = Deduplicator()
    assert _real_stream(dedup, range(1, 11)) == list(range(1, 11))
    for forged in (10 + 999, 10 + 5, 10 + 10**9, 2**64 - 1):
        assert [s for s, _, _ in dedup.fresh(9, forged, 0, "forged", {})] == [forged]
    got = _real_stream(dedup, range(11, 2011))
    assert got == [s for s in range(11, 2011) if s not in (15, 1009)]   # only the two seqs it took


def test_flooding_new_epochs_never_silences_the_real_stream() -> None:
    rng = random.Random(3)
    dedup = Deduplicator()
    delivered = []
    for seq in range(1, 3001):
        for _ in range(rng.randrange(0, 12)):          # spoofed samples: random far seqs, same id
            dedup.fresh(9, rng.randrange(10**6, 2**64), 0, "forged", {})
        delivered += _real_stream(dedup, [seq])
        if rng.random() < 0.5:                         # a repeated copy of the real packet
            delivered += _real_stream(dedup, [seq])
    assert delivered == list(range(1, 3001))             # every real sample, once, in order
    assert len(dedup) == 1 and len(dedup._pubs[9]) <= 4  # bounded epochs


def test_history_is_capped_and_deduplicated() -> None:
    dedup = Deduplicator()
    dedup.fresh(1, 1, 0, "a", {})
    huge = {"r": [[s, 0, "h"] for s in range(2, 1002)]}
    assert [s for s, _, _ in dedup.fresh(1, 1002, 0, "x", huge)] == [1002]    # over 64 entries: ignored
    assert dedup.history_rejected == 1
    twice = {"r": [[1003, 0, "h"], [1003, 0, "h"], [1004, 0, "h"]]}
    assert [s for s, _, _ in dedup.fresh(1, 1005, 0, "x", twice)] == [1003, 1004, 1005]


def test_publisher_table_is_bounded() -> None:
    dedup = Deduplicator()
    for pub in range(30_000):
        dedup.fresh(pub, 1, 0, "x", {})
    assert len(dedup) == Deduplicator.MAX_PUBLISHERS


def test_deadline_copies_are_spread_and_a_newer_payload_replaces_them() -> None:
    import threading
    import time

    from zenoh_robot.repeater import Repeater

    sent: list[tuple[float, bytes]] = []
    lock = threading.Lock()

    def put(b: bytes) -> None:
        with lock:
            sent.append((time.monotonic(), b))

    r = Repeater()
    try:
        t0 = time.monotonic()
        r.schedule_latest(1, put, b"old", copies=10, window=0.2)
        time.sleep(0.05)
        r.schedule_latest(1, put, b"new", copies=10, window=0.2)
        r.schedule_latest(2, put, b"other", copies=2, window=0.2)   # another key is untouched
        time.sleep(0.45)
    finally:
        r.close()
    with lock:
        old = [t - t0 for t, b in sent if b == b"old"]
        new = [b for _, b in sent if b == b"new"]
        other = [b for _, b in sent if b == b"other"]
    # Spread over the window, not bunched: before the newer payload only the first ~2 of 10 went.
    assert 1 <= len(old) <= 4, old
    assert len(new) == 10 and len(other) == 2


def test_a_starved_repeater_counts_the_copies_it_sent_late() -> None:
    """A copy held back past its time leaves together with the next ones (one datagram, lost
    together): the repeater counts it, so a flight's record tells a starved thread from the link."""
    import threading

    from zenoh_robot.repeater import LATE_S, Repeater

    hold = threading.Event()
    sent: list[bytes] = []

    def put(b: bytes) -> None:
        if b == b"slow":
            hold.wait(5.0)          # the repeater's thread is busy: everything after it is due meanwhile
        sent.append(b)

    r = Repeater()
    try:
        r.schedule(put, b"slow", copies=1, interval=0.001)
        r.schedule(put, b"next", copies=5, interval=0.005)
        time.sleep(0.15)            # all of "next" is due, and late by more than LATE_S
        assert r.stats()["sent"] == 1 and r.stats()["late"] == 0
        hold.set()
        deadline = time.monotonic() + 5.0
        while len(sent) < 6 and time.monotonic() < deadline:
            time.sleep(0.01)
        stats = r.stats()
    finally:
        r.close()
    assert sent == [b"slow"] + [b"next"] * 5
    assert stats["sent"] == 6 and stats["late"] >= 5, stats
    assert stats["max_late_ms"] >= 100 > LATE_S * 1000, stats


def test_a_node_reports_its_repeater_only_once_something_repeated(ns: str) -> None:
    from zenoh_robot import qos
    from zenoh_robot.msgs import Setpoint

    with Node("rep", namespace=ns) as node:
        assert node.repeater_stats() is None
        pub = node.create_publisher(Setpoint, "setpoint", qos.SETPOINT.replace(repeat=3))
        pub.publish(Setpoint(x=1.0))
        deadline = time.monotonic() + 5.0
        while (node.repeater_stats() or {}).get("sent", 0) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        stats = node.repeater_stats()
    assert stats is not None and stats["sent"] == 3 and stats["dropped"] == 0, stats


def test_repeat_plan_follows_loss_and_bounds_cost() -> None:
    from zenoh_robot.loss_feedback import repeat_plan
    plans = {p: repeat_plan(p, 0.5) for p in (0.0, 0.3, 0.5, 0.7, 0.9)}
    rates = {p: c / w for p, (c, w) in plans.items()}          # copies per second while samples flow
    assert rates[0.0] <= 41 and list(rates.values()) == sorted(rates.values())
    for p, rate in rates.items():
        # Every 400 ms window must hold enough packets that losing all of them is < 1e-4 likely.
        assert p ** (0.4 * rate) < 1e-4, (p, plans[p])
    assert plans[0.9][0] == 64 and plans[0.9][1] < 0.4            # 64 copies, packed closer


def test_loss_monitor_measures_silence_and_adapts_a_publisher(ns: str) -> None:
    """Two nodes probe each other: no loss measured; when one goes silent the other sees ~100 %,
    and the adapter re-sizes a real deadline publisher's copies from it."""
    from zenoh_robot.loss_feedback import LossMonitor, apply_repeat_plan
    from zenoh_robot.msgs import Header
    from zenoh_robot.qos import RESILIENT

    listen, connect = linked_configs()
    with Node("a", namespace=ns, config=listen) as a, Node("b", namespace=ns, config=connect) as b:
        pub = a.create_publisher(Header, "sp", RESILIENT.replace(deadline=0.5, repeat=64))
        ma, mb = LossMonitor(a, "gcs", topic=f"/{ns}/link"), LossMonitor(b, "drone", topic=f"/{ns}/link")
        seen: list[float] = []
        ma.adapt(lambda p: (seen.append(p), apply_repeat_plan(pub, p)))
        try:
            # Callbacks run on the node's executor: spin a (b's probes are what a measures).
            assert a.spin_until(lambda: len(seen) > 25 and seen[-1] < 0.2, 6.0), seen[-5:]
            assert pub.repeats == 16 and abs(pub.repeat_window - 0.4) < 1e-9
            assert [p.origin for p in ma._peers.values()] == [ns]   # the probe names its node's namespace
            mb.close()                          # b falls silent: a must see it as loss within ~1 s
            assert a.spin_until(lambda: ma.outgoing_loss() >= 0.9, 4.0), ma.outgoing_loss()
            time.sleep(0.2)
            assert pub.repeats == 64 and pub.repeat_window < 0.4
        finally:
            ma.close()
            mb.close()


def _reference_loss(arrivals: list[float], first_seen: float, period: float, now: float,
                    windows: tuple[float, float]) -> float:
    """The monitor's estimate as it was computed before the running counts: a rescan of every arrival."""
    worst = 0.0
    for window in windows:
        span = min(window, now - first_seen)
        if span < 4 * period:
            continue
        got = sum(1 for t in arrivals[-2048:] if t > now - span)
        worst = max(worst, 1.0 - min(1.0, got / (span / period)))
    return worst


def test_loss_monitor_running_counts_measure_the_same_loss_as_a_rescan(monkeypatch) -> None:
    """A synthetic probe pattern (clean, 30 % random loss, a 95 % burst, silence, a peer joining late):
    at every 20 Hz tick the monitor's per-window counts give the loss a full rescan gives."""
    from conftest import bare_loss_monitor

    from zenoh_robot.loss_feedback import LinkProbe

    m, clock = bare_loss_monitor(monkeypatch)   # the estimator alone, on the test's clock

    rnd = random.Random(17)
    sent: dict[int, list[float]] = {2: [], 3: []}
    first: dict[int, float] = {}
    checked = 0
    for step in range(600):                      # 30 s of 50 ms probes from peer 2; peer 3 from 12 s
        t = 1000.0 + step * 0.05
        for pid in (2, 3):
            if pid == 3 and t < 1012.0:
                continue
            drop = 0.3 if t < 1008 else 0.95 if t < 1011 else 1.0 if 1020 <= t < 1022 else 0.0
            if rnd.random() < drop:
                continue
            clock[0] = t + rnd.uniform(0.0, 0.004)   # jitter on arrival
            m._on_probe(LinkProbe(pid, step, 50, [], []))
            sent[pid].append(clock[0])
            first.setdefault(pid, clock[0])
        clock[0] = t + 0.025                       # the monitor's tick, between probes
        got = m.incoming_loss()
        for pid, arrivals in sent.items():
            if pid not in got:
                continue
            want = _reference_loss(arrivals, first[pid], 0.05, clock[0], (1.0, 5.0))
            assert abs(got[pid] - want) < 1e-12, (step, pid, got[pid], want)
            checked += 1
    assert checked > 900
    assert m.incoming_loss()[2] < 0.5            # the estimate moved: the pattern exercised it
