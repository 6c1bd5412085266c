"""An idle node sleeps: a free-running spin and the QoS monitor wake only for work, timers, shutdown and
signals (each idle wake-up of a thread costs ~0.15 ms of CPU; zenoh_robot/executor.py)."""
from __future__ import annotations

import signal
import threading
import time
from typing import Any

import pytest
from conftest import python_proc, wait_for

from zenoh_robot import MultiThreadedExecutor
from zenoh_robot.executor import Executor, Timer
from zenoh_robot.qos_monitor import QoSMonitor


def _counting(executor: Executor) -> list[int]:
    turns = [0]
    original = executor._spin_once

    def counted(timeout: float | None, free: bool) -> bool:
        turns[0] += 1
        return original(timeout, free)
    executor._spin_once = counted  # type: ignore[method-assign]
    return turns


@pytest.mark.fast
def test_an_idle_free_spin_sleeps_until_work_a_timer_or_shutdown_wakes_it() -> None:
    executor = Executor()
    turns = _counting(executor)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    time.sleep(1.0)
    # Before: a turn every 100 ms (10 in this second). A loaded machine gives fewer turns, never more.
    assert turns[0] <= 2, f"an idle spin turned {turns[0]} times in a second"
    ran = threading.Event()
    executor.submit(ran.set)
    assert ran.wait(5.0), "submitted work never ran"
    fired = threading.Event()
    executor.add_timer(Timer(0.05, fired.set, executor))
    assert fired.wait(5.0), "a timer added while the spin slept never fired"
    executor.shutdown()
    spinner.join(5.0)
    assert not spinner.is_alive(), "shutdown did not end the spin"


@pytest.mark.fast
def test_shutdown_ends_every_thread_of_an_idle_multithreaded_spin() -> None:
    executor = MultiThreadedExecutor(num_threads=4)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    assert wait_for(lambda: sum(t.name.startswith("zr-executor-") for t in threading.enumerate()) >= 3, 5.0)
    time.sleep(0.2)     # every thread asleep in its wait
    executor.shutdown()
    # shutdown() wakes one thread; each one that leaves wakes the next (else the others sleep out their wait).
    assert wait_for(lambda: not spinner.is_alive()
                    and not any(t.name.startswith("zr-executor-") and t.is_alive() for t in threading.enumerate()),
                    5.0), [t.name for t in threading.enumerate()]


@pytest.mark.fast
def test_the_qos_monitor_does_not_tick_while_nothing_is_registered() -> None:
    monitor = QoSMonitor()
    try:
        waits = [0]
        event = monitor._wake

        class Counting(threading.Event):
            def wait(self, timeout: float | None = None) -> bool:
                waits[0] += 1
                return event.wait(timeout)

            def set(self) -> None:
                event.set()

            def clear(self) -> None:
                event.clear()
        monitor._wake = Counting()
        time.sleep(0.6)
        assert waits[0] == 0, f"the monitor woke {waits[0]} times with nothing to check (before: every 100 ms)"
        ticked = threading.Event()

        class Entity:
            tick_period = 0.04

            def tick(self, now: float) -> Any:
                ticked.set()
        monitor.register(Entity())
        assert ticked.wait(5.0), "a registered entity was never ticked"
    finally:
        monitor.close()


def test_ctrl_c_ends_an_idle_spin_on_the_main_thread() -> None:
    """A free spin on the main thread sleeps up to 10 s in SimpleQueue.get: Ctrl-C must still end it at once
    (the signal interrupts the wait and raises there; a job started with SIGINT ignored, as a shell's
    background job is, never sees it at all)."""
    # The handler set explicitly: a test run started in the background passes an ignored SIGINT on to its children.
    proc = python_proc("-c", "import signal\n"
                       "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
                       "from zenoh_robot.executor import Executor\n"
                       "e = Executor()\n"
                       "print('READY', flush=True)\n"
                       "try:\n"
                       "    e.spin()\n"
                       "except KeyboardInterrupt:\n"
                       "    print('INTERRUPTED', flush=True)\n")
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "READY"
        time.sleep(0.3)     # asleep in its wait
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=5.0)   # a wait that sat the signal out would time this out
        assert "INTERRUPTED" in out and proc.returncode == 0, out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
