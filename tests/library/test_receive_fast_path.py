"""A plain publisher's samples and a redundant one's (extra fields: deduplication turns on for the whole
subscription at its first sample) give the callback, the hooks and the counters the same on the default
receive path, including when a stream switches from one to the other. (Issue #43 tried delivering the plain
case inline in ``Subscription._handle``, measured 3 % of the receive Python and kept one path; this holds
any such split to the same behaviour.)"""
from __future__ import annotations

import time
from typing import Any

import pytest
from conftest import linked_nodes

from zenoh_robot import QoSProfile
from zenoh_robot.msgs import Setpoint

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def test_plain_and_redundant_publishers_are_delivered_alike(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[tuple[int, int, float, int]] = []
        hooked: list[tuple[int, int]] = []
        sub = b.create_subscription(
            Setpoint, "sp", lambda m, info: got.append((info.publisher_id, info.seq, m.x, info.source_stamp_ns)),
            QoSProfile(depth=100))
        sub.sample_hooks.append(lambda m, info: hooked.append((info.publisher_id, info.seq)))
        plain = a.create_publisher(Setpoint, "sp", QoSProfile(depth=100))
        redundant = a.create_publisher(Setpoint, "sp", QoSProfile(depth=100, redundancy=2))
        time.sleep(0.3)
        sent: list[tuple[int, int, float, int]] = []
        for i in range(5):      # the plain publisher alone first: the inline path
            p = plain.publish(Setpoint(x=float(i)))
            sent.append((plain.publisher_id, p.seq, float(i), p.stamp_ns))
        assert b.spin_until(lambda: len(got) == 5, 5.0), sub.counters
        assert sub.dedup is None
        for i in range(5, 15):  # then both: from the first redundant sample on, the general path
            p = plain.publish(Setpoint(x=float(i)))
            sent.append((plain.publisher_id, p.seq, float(i), p.stamp_ns))
            r = redundant.publish(Setpoint(x=100.0 + i))
            sent.append((redundant.publisher_id, r.seq, 100.0 + i, r.stamp_ns))
        assert b.spin_until(lambda: len(got) == 25, 5.0), sub.counters
        time.sleep(0.2)
        b.spin_once(0.05)
        assert sorted(got) == sorted(sent)          # each sample once, with its own header
        assert sorted(hooked) == sorted((g[0], g[1]) for g in got)
        assert sub.dedup is not None
        c = sub.counters
        assert (c.received, c.delivered, c.lost, c.dropped, c.malformed, c.hook_errors) == (25, 25, 0, 0, 0, 0)


def test_a_raising_hook_or_callback_is_counted_on_the_inline_path(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        calls: list[Any] = []

        def callback(m: Setpoint) -> None:     # one argument: no MessageInfo unless a hook wants one
            calls.append(m.x)
            if m.x == 1.0:
                raise RuntimeError("callback failed on purpose")

        def hook(m: Setpoint, info: Any) -> None:
            if info.seq == 3:
                raise RuntimeError("hook failed on purpose")
        sub = b.create_subscription(Setpoint, "sp", callback, QoSProfile(depth=10))
        sub.sample_hooks.append(hook)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=10))
        time.sleep(0.3)
        for i in range(4):
            pub.publish(Setpoint(x=float(i)))
        assert b.spin_until(lambda: len(calls) == 4, 5.0), sub.counters
        c = sub.counters
        assert calls == [0.0, 1.0, 2.0, 3.0]        # the sample whose hook raised is still delivered
        assert (c.delivered, c.callback_errors, c.hook_errors, c.lost) == (3, 1, 1, 0)


def test_the_per_sample_bench_measures_every_step_and_loses_nothing() -> None:
    # docs/benchmarks.md (#43) quotes `python -m zenoh_robot.tools.bench.persample`: it must keep running
    # the receive path it describes (it raises if a sample went missing). Figures only, no timing asserted.
    from zenoh_robot.tools.bench.persample import measure
    figures = measure("setpoint", count=200, reps=1)
    assert set(figures) == {"publish", "raw publish", "zenoh thread", "executor", "raw callback", "receive"}
    assert all(v > 0 for v in figures.values())
