"""The channel receive path (issue #30) over real Zenoh sessions: Zenoh's ring channel drained by the
executor in batches keeps order, bounds, counters and QoS events, and runs no Python per sample on
Zenoh's threads."""
from __future__ import annotations

import threading
import time
from typing import Any

import msgpack
import pytest
from conftest import linked_nodes

from zenoh_robot import QoSProfile
from zenoh_robot.events import SubscriptionEventCallbacks
from zenoh_robot.msgs import Float32, Setpoint
from zenoh_robot.qos import HistoryPolicy
from zenoh_robot.subscription import DRAIN_BATCH, Subscription

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=0)


def _blocking_put(session: Any, key: str) -> Any:
    import zenoh
    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK).put


def test_channel_path_keeps_order_across_batches_on_the_executor_thread(ns: str, monkeypatch: Any) -> None:
    calls = {"on_sample": 0}
    original = Subscription._on_sample

    def counting(self: Subscription[Any], sample: Any) -> None:
        calls["on_sample"] += 1
        original(self, sample)
    monkeypatch.setattr(Subscription, "_on_sample", counting)
    n = 20 * DRAIN_BATCH + 7
    with linked_nodes(ns) as (a, b):
        got: list[int] = []
        threads: set[int] = set()

        def on_msg(m: Setpoint, info: Any) -> None:
            got.append(info.seq)
            threads.add(threading.get_ident())
        sub = b.create_subscription(Setpoint, "sp", on_msg, KEEP_ALL, receive="channel")
        assert sub.receive == "channel"
        pub = a.create_publisher(Setpoint, "sp", KEEP_ALL)
        time.sleep(0.3)
        for i in range(n):
            pub.publish(Setpoint(x=float(i)))
        assert b.spin_until(lambda: len(got) == n, 10.0), sub.counters
        assert got == list(range(1, n + 1))
        assert threads == {threading.get_ident()}          # the test's spin is the executor
        c = sub.counters
        assert c.received == c.delivered == n and c.lost == 0 and c.dropped == 0 and c.internal_errors == 0
        assert calls["on_sample"] == 0      # no Python callback ran on Zenoh's threads
        # The old path still is the default, and it does run one.
        cb_got: list[Setpoint] = []
        cb_sub = b.create_subscription(Setpoint, "sp", cb_got.append, KEEP_ALL)
        assert cb_sub.receive == "callback"
        time.sleep(0.3)
        pub.publish(Setpoint())
        assert b.spin_until(lambda: len(cb_got) == 1, 5.0)
        assert calls["on_sample"] >= 1


def _keep_last_5(a: Any, b: Any, got: list[int]) -> tuple[Any, Any]:
    """A KEEP_LAST(5) channel subscription on ``b`` recording sequence numbers, and its publisher on ``a``."""
    sub = b.create_subscription(Setpoint, "sp", lambda m, info: got.append(info.seq), QoSProfile(depth=5),
                                receive="channel")
    pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=5))
    time.sleep(0.3)
    return sub, pub


def test_channel_path_keep_last_holds_only_the_newest_depth_samples(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[int] = []
        sub, pub = _keep_last_5(a, b, got)
        for i in range(100):        # nobody spins: Zenoh's ring keeps the newest 5
            pub.publish(Setpoint(x=float(i)))
        time.sleep(0.5)
        assert b.spin_until(lambda: got and got[-1] == 100, 5.0), (got, sub.counters)
        b.spin_until(lambda: False, 0.2)
        assert got == [96, 97, 98, 99, 100]
        # The waiter's sample, when it took one before the burst (older than the 5 in the ring), is
        # dropped and counted, as the callback path would; the ring's own overwrites are not seen by
        # Python (the module doc says so).
        c = sub.counters
        assert c.dropped in (0, 1) and c.received == 5 + c.dropped and c.delivered == 5 and c.lost == 0
        assert not sub.pending


def test_channel_path_keep_last_under_depth_delivers_the_waiters_sample_first(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[int] = []
        sub, pub = _keep_last_5(a, b, got)
        for burst in (1, 3, 2):     # nobody spins: the waiter holds the first, the ring the rest
            start = len(got)
            for _ in range(burst):
                pub.publish(Setpoint(x=0.0))
            time.sleep(0.3)
            want = start + burst
            assert b.spin_until(lambda want=want: len(got) == want, 5.0), (got, sub.counters)
        b.spin_until(lambda: False, 0.2)
        assert got == [1, 2, 3, 4, 5, 6]
        c = sub.counters
        assert c.received == c.delivered == 6 and c.dropped == c.lost == 0 and not sub.pending


def test_channel_path_counts_malformed_and_oversize_and_keeps_draining(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[float] = []
        sub = b.create_subscription(Setpoint, "sp", lambda m: got.append(m.x), KEEP_ALL, receive="channel")
        sub.max_sample_bytes = 4096
        pub = a.create_publisher(Setpoint, "sp", KEEP_ALL)
        put = _blocking_put(a.session, sub.data_key)
        time.sleep(0.3)
        for i in range(30):
            put(b"\x93garbage" * (i % 3))                                      # not an envelope
            put(msgpack.packb(["zr1", "x", "y", 1, 1, 0, [], {}]) + b"")      # another type, same key
            put(b"\x00" * 10_000)                                               # over max_sample_bytes
            pub.publish(Setpoint(x=float(i)))
        assert b.spin_until(lambda: len(got) == 30 and sub.counters.received == 120, 10.0), sub.counters
        c = sub.counters
        assert got == [float(i) for i in range(30)]
        assert c.oversize == 30 and c.malformed + c.type_mismatch == 60 and c.internal_errors == 0
        assert c.delivered == 30


def test_channel_path_deadline_events_on_time_and_none_while_samples_flow(ns: str) -> None:
    events: list[Any] = []
    with linked_nodes(ns) as (a, b):
        q = QoSProfile(depth=5, deadline=0.2)
        got: list[float] = []
        b.create_subscription(Float32, "hb", lambda m: got.append(m.data), q, receive="channel",
                              event_callbacks=SubscriptionEventCallbacks(deadline=events.append))
        pub = a.create_publisher(Float32, "hb", q)
        b.spin_until(lambda: False, 0.3)
        for _ in range(16):       # 20 Hz for 0.8 s: inside the 200 ms deadline
            pub.publish(Float32(1.0))
            b.spin_until(lambda: False, 0.05)
        assert len(got) >= 14 and events == []
        b.spin_until(lambda: False, 0.75)     # silence: about three periods
        assert events and 2 <= events[-1].total_count <= 5, events


def test_channel_path_a_flood_does_not_hold_back_another_topic(ns: str) -> None:
    """The setpoint path never waits behind heavy decoding: a drain turn takes at most DRAIN_BATCH samples."""
    with linked_nodes(ns) as (a, b):
        order: list[str] = []
        b.create_subscription(Setpoint, "flood", lambda m: (order.append("f"), time.sleep(0.0002)), KEEP_ALL,
                              receive="channel")
        b.create_subscription(Setpoint, "sp", lambda m: order.append("s"), QoSProfile(depth=1), receive="channel")
        flood = a.create_publisher(Setpoint, "flood", KEEP_ALL)
        sp = a.create_publisher(Setpoint, "sp", QoSProfile(depth=1))
        time.sleep(0.3)
        n = 40 * DRAIN_BATCH
        for _ in range(n):
            flood.publish(Setpoint())
        time.sleep(0.3)     # all of the flood is in Zenoh's channel before the setpoint
        sp.publish(Setpoint())
        time.sleep(0.2)
        assert b.spin_until(lambda: order.count("f") == n and "s" in order, 20.0), len(order)
        assert order.index("s") <= 2 * DRAIN_BATCH + 1, order.index("s")


def test_channel_path_destroy_stops_delivery_and_the_waiter_ends_with_the_session(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[Setpoint] = []
        sub = b.create_subscription(Setpoint, "sp", got.append, QoSProfile(depth=5), receive="channel")
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=5))
        time.sleep(0.3)
        pub.publish(Setpoint())
        assert b.spin_until(lambda: len(got) == 1, 5.0)
        sub.destroy()
        pub.publish(Setpoint())
        b.spin_until(lambda: False, 0.3)
        assert len(got) == 1
    sub._waiter.join(5.0)
    assert not sub._waiter.is_alive()


def test_receive_must_name_a_path(ns: str) -> None:
    with linked_nodes(ns) as (_, b), pytest.raises(ValueError, match="receive"):
        b.create_subscription(Setpoint, "sp", print, QoSProfile(depth=5), receive="poll")


def test_an_idle_free_spinning_executor_lets_the_waiter_run_the_drain_never_concurrently(ns: str) -> None:
    """Issue #30's latency step: a node spinning freely (``spin()``) and idle has a channel sample handled on
    the subscription's own waiter thread (no second wake-up), under the executor's run lock: a timer
    callback of the same node never overlaps it, and the node's own spin still runs the timers."""
    with linked_nodes(ns) as (a, b):
        inside = threading.Event()
        overlaps: list[str] = []
        where: list[str] = []
        ticks: list[str] = []

        def on_msg(m: Setpoint) -> None:
            if inside.is_set():
                overlaps.append("callback")
            inside.set()
            where.append(threading.current_thread().name)
            time.sleep(0.002)
            inside.clear()

        def on_tick() -> None:
            if inside.is_set():
                overlaps.append("timer")
            ticks.append(threading.current_thread().name)
        sub = b.create_subscription(Setpoint, "sp", on_msg, QoSProfile(depth=5), receive="channel")
        b.create_timer(0.001, on_tick)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=5))
        spinner = threading.Thread(target=b.spin, name="node-spin", daemon=True)
        spinner.start()
        try:
            time.sleep(0.3)
            for _ in range(200):
                pub.publish(Setpoint())
                time.sleep(0.003)
            deadline = time.monotonic() + 5.0
            while sub.counters.delivered + sub.counters.dropped < 200 and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            b.executor.shutdown()
            spinner.join(5.0)
        assert sub.counters.delivered > 0 and not overlaps, overlaps[:5]
        assert any(name.startswith("zr-recv-") for name in where), set(where)   # handled in place
        assert b.executor.ran_in_place > 0
        assert ticks and set(ticks) == {"node-spin"}


def test_run_here_refuses_while_nobody_spins_freely(ns: str) -> None:
    """spin_once / spin_until callers must see the work they wait for run in their own loop."""
    with linked_nodes(ns) as (_, b):
        ran: list[int] = []
        assert not b.executor.run_here(lambda: ran.append(1))
        t = threading.Thread(target=b.spin_until, args=(lambda: False, 0.3), daemon=True)
        t.start()
        time.sleep(0.1)
        assert not b.executor.run_here(lambda: ran.append(2))
        t.join(5.0)
        assert ran == []


@pytest.mark.parametrize("qos", [KEEP_ALL, QoSProfile(depth=DRAIN_BATCH)], ids=["keep_all", "keep_last"])
def test_a_drain_that_empties_the_queue_unschedules_at_once(ns: str, qos: QoSProfile) -> None:
    """A turn that handles exactly DRAIN_BATCH samples and leaves nothing behind leaves no drain queued
    (CI saw a spin_until return with a needless second drain still scheduled)."""
    with linked_nodes(ns) as (a, b):
        got: list[Setpoint] = []
        sub = b.create_subscription(Setpoint, "sp", got.append, qos)
        pub = a.create_publisher(Setpoint, "sp", qos)
        time.sleep(0.3)
        for i in range(DRAIN_BATCH):
            pub.publish(Setpoint(x=float(i)))
        deadline = time.monotonic() + 10.0
        while sub.counters.received < DRAIN_BATCH and time.monotonic() < deadline:
            time.sleep(0.01)     # nobody spins: the samples wait in the subscription's queue
        assert sub.counters.received == DRAIN_BATCH and sub.pending == DRAIN_BATCH
        assert b.executor.spin_once(5.0)           # one turn drains them all
        assert len(got) == DRAIN_BATCH and not sub.pending
        assert not sub._scheduled and sub._queued_bytes == 0
        assert not b.executor.spin_once(0.0)       # and nothing is left for the executor to run
