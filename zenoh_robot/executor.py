"""Executors: run callbacks on the node's own thread(s), never on Zenoh's.

Zenoh callbacks only enqueue (a subscription schedules itself at most once until it
has been drained), so the ready queue is bounded by the number of entities plus a
bounded number of events; the work itself is queued in each entity's bounded queue.

Hand-off without a thread hop (issues #30, #43): a delivery thread that has work while the
single-threaded executor sits idle in a free-running ``spin()`` may run that work itself
(``run_here``): a channel subscription's waiter, or zenoh-python's per-subscriber delivery thread
for a lone sample (never a thread of Zenoh's own runtime: ``zenoh_robot/subscription.py`` says how
long a drain may hold one). The executor's run lock keeps callbacks one at a time, exactly as if
the executor had run it, and the sample skips the wake-up of a second thread (CPU per message and
p50 latency, docs/benchmarks.md). Never while the executor is busy, never while a caller spins
with ``until``/``timeout`` or ``spin_once`` (they must see the work they wait for run in their own
loop), never on a multi-threaded executor. A callback run in place that spins the executor itself (a
nested spin, waiting for another callback) lets go of the run lock while it spins: the executor's own
thread may hold the work it waits for (``_pause_in_place``).
"""
from __future__ import annotations

import heapq
import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable

log = logging.getLogger("zenoh_robot.executor")
_get_ident = threading.get_ident

Work = Callable[[], None]
# How long a free-running spin with nothing to do sleeps before it looks again; nothing needs the look
# (shutdown, timers and signals wake it), it only bounds the cost of a wake-up that was missed.
FREE_SPIN_WAIT_S = 10.0


class Timer:
    """A periodic callback run by the executor (``Node.create_timer``)."""

    def __init__(self, period_s: float, callback: Callable[[], None], executor: "Executor") -> None:
        if not period_s > 0:
            raise ValueError(f"timer period must be > 0 seconds, got {period_s!r}")
        self.period = float(period_s)
        self.callback = callback
        self._executor = executor
        self._canceled = False
        self.next_call = time.monotonic() + self.period

    def cancel(self) -> None:
        self._canceled = True

    def reset(self) -> None:
        self._canceled = False
        self.next_call = time.monotonic() + self.period
        self._executor.add_timer(self)

    @property
    def is_canceled(self) -> bool:
        return self._canceled

    def time_until_next_call(self) -> float:
        return max(0.0, self.next_call - time.monotonic())


class Executor:
    """Single-threaded: callbacks never run concurrently (rclpy's SingleThreadedExecutor)."""

    MAX_PENDING_CALLS = 10_000

    def __init__(self) -> None:
        self._ready: queue.SimpleQueue[Work | None] = queue.SimpleQueue()
        self._timers: list[tuple[float, int, Timer]] = []
        # The heap's earliest entry (a canceled timer's too: then _due_timer only cleans up). Read
        # without the lock by spin_once, so a turn with no timer due takes no lock and no heap look.
        self._next_due = float("inf")
        self._timer_lock = threading.Lock()
        self._counter = itertools.count()
        self._shutdown = threading.Event()
        self._pending_calls = 0
        self._pending_lock = threading.Lock()
        # Held while any callback runs (here or on a thread that runs work in place: run_here);
        # re-entrant, as a callback that spins the executor itself (a nested spin) must not deadlock.
        self._run_lock = threading.RLock()
        # Free-running spins blocked waiting for work: a hint read without a lock; the run lock decides.
        self._idle_free = 0
        # The thread running work in place now (its ident), 0 when none: a spin on that thread is a nested
        # spin of a paused callback (see _pause_in_place).
        self._in_place_thread = 0
        self.dropped_calls = 0
        self.errors = 0
        self.ran_in_place = 0

    # -- scheduling (any thread) -------------------------------------------------
    def submit(self, work: Work) -> None:
        """Queue an entity's drain function; callers guarantee at most one per entity."""
        self._ready.put(work)

    def call_soon(self, fn: Work) -> bool:
        """Queue a one-off call (events, replies); bounded: returns False and counts when full."""
        with self._pending_lock:
            if self._pending_calls >= self.MAX_PENDING_CALLS:
                self.dropped_calls += 1
                return False
            self._pending_calls += 1

        def run() -> None:
            with self._pending_lock:
                self._pending_calls -= 1
            fn()
        self._ready.put(run)
        return True

    def add_timer(self, timer: Timer) -> None:
        with self._timer_lock:
            heapq.heappush(self._timers, (timer.next_call, next(self._counter), timer))
            self._next_due = self._timers[0][0]
        self._ready.put(None)  # wake a waiting spin so it recomputes its timeout

    def run_here(self, work: Work) -> bool:
        """Run ``work`` on the calling thread if the executor is idle in a free-running spin (see the
        module doc); False: the caller must ``submit`` it instead."""
        if not self.enter_in_place():
            return False
        try:
            work()
        except Exception:
            self.errors += 1
            log.exception("callback raised; the node keeps running")
        except BaseException as exc:
            self.raise_in_spin(exc)
        finally:
            self.leave_in_place()
        return True

    def raise_in_spin(self, exc: BaseException) -> None:
        """A callback run in place raised SystemExit or KeyboardInterrupt: raise it from the spin, where it
        would have come from had the executor run the callback (the delivery thread must go on)."""
        def rethrow() -> None:
            raise exc
        self._ready.put(rethrow)

    def enter_in_place(self) -> bool:
        """``run_here`` for a caller that runs its work inline (no callable made per sample): True means the
        run lock is held and the caller must call :meth:`leave_in_place` once its work is done."""
        if self._idle_free <= 0 or not self._run_lock.acquire(blocking=False):
            return False
        if self._idle_free <= 0 or self._shutdown.is_set():
            self._run_lock.release()
            return False
        self._in_place_thread = _get_ident()
        self.ran_in_place += 1
        return True

    def leave_in_place(self) -> None:
        self._in_place_thread = 0
        self._run_lock.release()

    def _pause_in_place(self) -> bool:
        """A callback run in place spins the executor (a nested spin, to wait for another callback's work):
        let go of the run lock while it spins, so that the executor's own thread, which may already have
        taken that work, can run it. Otherwise that thread would wait for the lock the paused callback holds
        and the nested spin for that work, until its timeout. Callbacks stay one at a time: every one
        runs under the lock, and the paused callback takes it back before its spin returns."""
        if self._in_place_thread != _get_ident():
            return False
        self._in_place_thread = 0
        self._run_lock.release()
        return True

    def _resume_in_place(self) -> None:
        self._run_lock.acquire()
        self._in_place_thread = _get_ident()

    def shutdown(self) -> None:
        self._shutdown.set()
        self._ready.put(None)

    @property
    def is_shutdown(self) -> bool:
        return self._shutdown.is_set()

    # -- running -----------------------------------------------------------------
    def _due_timer(self) -> tuple[Timer | None, float]:
        """Pop a due timer, or return (None, seconds until the next one)."""
        with self._timer_lock:
            timers = self._timers
            try:
                while timers:
                    when, _, timer = timers[0]
                    if timer.is_canceled or when != timer.next_call:
                        heapq.heappop(timers)
                        continue
                    now = time.monotonic()
                    if when > now:
                        return None, when - now
                    heapq.heappop(timers)
                    # Keep the phase; if we fell far behind, skip missed ticks rather than burst.
                    timer.next_call = max(when + timer.period, now)
                    heapq.heappush(timers, (timer.next_call, next(self._counter), timer))
                    return timer, 0.0
                return None, float("inf")
            finally:
                self._next_due = timers[0][0] if timers else float("inf")

    def _run(self, fn: Callable[[], None], what: str) -> None:
        with self._run_lock:
            try:
                fn()
            except Exception:
                self.errors += 1
                log.exception("%s raised; the node keeps running", what)

    def spin_once(self, timeout: float | None = None) -> bool:
        """Run one piece of ready work (a timer or an entity's queue); False if none came."""
        paused = self._pause_in_place()
        try:
            return self._spin_once(timeout, False)
        finally:
            if paused:
                self._resume_in_place()

    def _spin_once(self, timeout: float | None, free: bool) -> bool:
        wait = self._next_due - time.monotonic()
        if wait <= 0:
            timer, wait = self._due_timer()
            if timer is not None:
                self._run(timer.callback, f"timer callback {timer.callback!r}")
                return True
        if timeout is not None:
            wait = min(wait, timeout)
        if free:
            self._idle_free += 1
        try:
            work = self._ready.get(timeout=None if wait == float("inf") else max(wait, 0.0))
        except queue.Empty:
            return self._fire_due_timer()
        finally:
            if free:
                self._idle_free -= 1
        if work is None:
            return self._fire_due_timer()
        self._run(work, "callback")
        return True

    def _fire_due_timer(self) -> bool:
        timer, _ = self._due_timer()
        if timer is None:
            return False
        self._run(timer.callback, f"timer callback {timer.callback!r}")
        return True

    def spin(self, until: Callable[[], bool] | None = None, timeout: float | None = None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        free = until is None and deadline is None
        in_place = free and self._in_place_allowed
        # A spin with `until` looks at it every 100 ms. A free-running one sleeps until its next timer or
        # work: shutdown() wakes it (put(None)), and so do a new timer and a signal. Each idle wake-up of a
        # thread costs ~0.15 ms of CPU here (measured: an idle node's 10 wake-ups a second were 1.4 ms/s,
        # raw zenoh-python's idle session 0.01 ms/s, docs/benchmarks.md).
        poll = FREE_SPIN_WAIT_S if free else 0.1
        paused = self._pause_in_place()
        try:
            while not self._shutdown.is_set():
                if until is not None and until():
                    return
                remaining = None
                if deadline is not None:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return
                self._spin_once(min(remaining, poll) if remaining is not None else poll, in_place)
        finally:
            if self._shutdown.is_set():
                self._ready.put(None)   # shutdown's one wake-up, handed on to the next spinning thread
            if paused:
                self._resume_in_place()

    # A multi-threaded executor's callbacks run concurrently: there the run lock would serialise them.
    _in_place_allowed = True


class MultiThreadedExecutor(Executor):
    """Runs ready work on ``num_threads`` threads; one entity's samples stay in order."""

    def __init__(self, num_threads: int = 4) -> None:
        super().__init__()
        if num_threads < 1:
            raise ValueError("num_threads must be >= 1")
        self.num_threads = num_threads

    _in_place_allowed = False

    def _run(self, fn: Callable[[], None], what: str) -> None:
        try:
            fn()
        except Exception:
            self.errors += 1
            log.exception("%s raised; the node keeps running", what)

    def spin(self, until: Callable[[], bool] | None = None, timeout: float | None = None) -> None:
        base_spin = super().spin   # super() needs the method's frame: resolve it here, not in a comprehension
        workers = [threading.Thread(target=base_spin, args=(until, timeout), daemon=True,
                                    name=f"zr-executor-{i}") for i in range(self.num_threads - 1)]
        for w in workers:
            w.start()
        try:
            base_spin(until, timeout)
        finally:
            if until is None and timeout is None:
                self.shutdown()
            for w in workers:
                w.join(timeout=1.0)
