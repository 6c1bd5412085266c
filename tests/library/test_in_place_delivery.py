"""The default receive path hands a lone sample to an idle executor without waking it (issue #43): the
drain runs on zenoh-python's delivery thread for the subscription, under the executor's run lock, so
callbacks stay one at a time; samples close behind each other, and a subscription whose callback once
ran long, go to the executor. Real Zenoh sessions."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from conftest import linked_nodes

from zenoh_robot import QoSProfile
from zenoh_robot import subscription as subscription_module
from zenoh_robot.msgs import Setpoint
from zenoh_robot.qos import HistoryPolicy

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

SPIN = "node-spin"


@contextmanager
def _spinning(b: Any) -> Iterator[None]:
    spinner = threading.Thread(target=b.spin, name=SPIN, daemon=True)
    spinner.start()
    try:
        yield
    finally:
        b.executor.shutdown()
        spinner.join(5.0)


def _wait(cond: Callable[[], bool], timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.01)
    return cond()


def test_a_lone_sample_is_handled_on_its_delivery_thread_one_callback_at_a_time(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        inside = threading.Event()
        overlaps: list[str] = []
        where: list[str] = []
        seqs: list[int] = []
        ticks: list[str] = []

        def on_msg(m: Setpoint, info: Any) -> None:
            if inside.is_set():
                overlaps.append("callback")
            inside.set()
            where.append(threading.current_thread().name)
            seqs.append(info.seq)
            time.sleep(0.001)
            inside.clear()

        def on_tick() -> None:
            if inside.is_set():
                overlaps.append("timer")
            ticks.append(threading.current_thread().name)
        sub = b.create_subscription(Setpoint, "sp", on_msg, QoSProfile(depth=50))
        assert sub.receive == "callback"
        b.create_timer(0.002, on_tick)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=50))
        with _spinning(b):
            time.sleep(0.3)
            for _ in range(100):
                pub.publish(Setpoint())
                time.sleep(0.004)      # alone: far more than IN_PLACE_GAP_NS apart
            assert _wait(lambda: sub.counters.delivered + sub.counters.dropped == 100), sub.counters
        assert not overlaps, overlaps[:5]
        assert seqs == sorted(seqs) and sub.counters.internal_errors == 0
        assert b.executor.ran_in_place > 0 and any(name != SPIN for name in where), set(where)
        assert ticks and set(ticks) == {SPIN}     # timers stay on the executor's own thread


def test_samples_close_behind_each_other_are_drained_by_the_executor(ns: str) -> None:
    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=0)
    with linked_nodes(ns) as (a, b):
        where: list[str] = []
        seqs: list[int] = []

        def on_msg(m: Setpoint, info: Any) -> None:
            where.append(threading.current_thread().name)
            seqs.append(info.seq)
        sub = b.create_subscription(Setpoint, "sp", on_msg, keep_all)
        pub = a.create_publisher(Setpoint, "sp", keep_all)
        with _spinning(b):
            time.sleep(0.3)
            for _ in range(500):       # back to back: Zenoh batches them, they arrive together
                pub.publish(Setpoint())
            assert _wait(lambda: len(seqs) == 500), sub.counters
        assert seqs == list(range(1, 501))
        c = sub.counters
        assert c.received == c.delivered == 500 and c.dropped == c.lost == 0
        assert SPIN in where        # a burst is the executor's, drained in batches


def test_a_callback_that_ran_long_in_place_sends_its_subscription_to_the_executor(
        ns: str, monkeypatch: Any) -> None:
    # A drain on the delivery thread holds that subscription's delivery channel (and, once it is full,
    # Zenoh's receive thread for the peer): one long run and the subscription never runs there again.
    monkeypatch.setattr(subscription_module, "IN_PLACE_SLOW_NS", 5_000_000)
    with linked_nodes(ns) as (a, b):
        where: list[str] = []

        def on_msg(m: Setpoint) -> None:
            where.append(threading.current_thread().name)
            if len(where) == 1:
                time.sleep(0.05)
        sub = b.create_subscription(Setpoint, "sp", on_msg, QoSProfile(depth=50))
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=50))
        with _spinning(b):
            time.sleep(0.3)
            pub.publish(Setpoint())
            assert _wait(lambda: len(where) == 1)
            first = where[0]
            assert _wait(lambda: sub.counters.delivered == 1)
            for _ in range(20):
                pub.publish(Setpoint())
                time.sleep(0.004)
            assert _wait(lambda: len(where) == 21), sub.counters
        assert first != SPIN          # the first ran in place (the executor was idle)...
        assert set(where[1:]) == {SPIN}, where    # ...and took over 5 ms: the rest are the executor's


@pytest.mark.parametrize("receive", ["callback", "channel"])
def test_a_system_exit_raised_in_place_ends_the_spin_and_the_subscription_goes_on(ns: str, receive: str) -> None:
    # The channel path's waiter runs drains in place too (Executor.run_here): before, a SystemExit there
    # ended the waiter thread, and its subscription delivered nothing more.
    with linked_nodes(ns) as (a, b):
        where: list[str] = []

        def on_msg(m: Setpoint) -> None:
            where.append(threading.current_thread().name)
            if len(where) == 1:
                raise SystemExit(3)
        sub = b.create_subscription(Setpoint, "sp", on_msg, QoSProfile(depth=50), receive=receive)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=50))
        outcome: list[Any] = []

        def spin() -> None:
            try:
                b.spin()
            except SystemExit as exc:
                outcome.append(exc.code)
        spinner = threading.Thread(target=spin, name=SPIN, daemon=True)
        spinner.start()
        time.sleep(0.3)
        pub.publish(Setpoint())
        spinner.join(10.0)
        assert outcome == [3]           # as if the executor had run the callback: the spin ends with it
        assert where[0] != SPIN         # it ran on the delivery thread
        pub.publish(Setpoint())
        assert b.spin_until(lambda: len(where) == 2, 10.0), sub.counters    # not stuck "scheduled"
        assert sub.counters.delivered == 1 and sub.counters.internal_errors == 0


def test_a_callback_run_in_place_that_spins_sees_the_callbacks_it_waits_for(ns: str) -> None:
    # A callback that spins the node until another topic's callback has run (rclpy users do this with a
    # nested spin): run in place, its spin must let that callback run, as the executor's own thread would
    # (there the nested spin runs it). Before, the node's spinning thread took the other callback's work
    # and then waited for the run lock the paused callback held: the nested spin ran out its timeout.
    with linked_nodes(ns) as (a, b):
        answers: list[int] = []
        waited: list[tuple[str, bool, float]] = []
        running: list[str] = []      # the callback running now, outside a nested spin
        overlaps: list[str] = []

        def enter(name: str) -> None:
            if running:
                overlaps.append(f"{name} while {running[-1]}")
            running.append(name)

        def on_answer(m: Setpoint) -> None:
            enter("answer")
            answers.append(1)
            time.sleep(0.005)     # the paused callback must not take the lock back meanwhile
            running.pop()

        def on_ask(m: Setpoint) -> None:
            enter("ask")
            t0 = time.monotonic()
            heard = len(answers)
            running.pop()         # paused: other callbacks may run in its nested spin
            got = b.spin_until(lambda: len(answers) > heard, 3.0)
            enter("ask, back from its spin")
            waited.append((threading.current_thread().name, got, time.monotonic() - t0))
            running.pop()
        b.create_subscription(Setpoint, "ask", on_ask, QoSProfile(depth=10))
        b.create_subscription(Setpoint, "answer", on_answer, QoSProfile(depth=10))
        ask = a.create_publisher(Setpoint, "ask", QoSProfile(depth=10))
        answer = a.create_publisher(Setpoint, "answer", QoSProfile(depth=10))
        with _spinning(b):
            time.sleep(0.3)
            for i in range(5):
                ask.publish(Setpoint())
                time.sleep(0.05)
                answer.publish(Setpoint())
                assert _wait(lambda n=i + 1: len(waited) == n, 5.0), (waited, answers)
                time.sleep(0.05)
        assert len(waited) == 5 and all(got for _, got, _ in waited), waited
        assert b.executor.ran_in_place > 0 and any(name != SPIN for name, _, _ in waited), waited
        assert not overlaps, overlaps
