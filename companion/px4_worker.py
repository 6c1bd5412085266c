"""Where the companion's PX4 work runs: a command lane, and a failsafe lane that never waits for it.

PX4 commands wait for an ACK (seconds): never on the executor's threads, nor on Zenoh's or
px4_link's. Two lanes, each its own thread:

- The command lane (``px4-cmd``): operator commands and lifecycle jobs, in order, one at a time.
  Bounded: at most ``MAX_QUEUED`` commands wait behind the running one; ``submit`` refuses more at
  once (``WorkerBusy``). A command has a deadline (the reply's timeout): one not started by then
  never starts, one still running then is abandoned (its future fails now and the COMMAND_LONG it
  waits on is withdrawn). ``expire`` enforces it (the companion's 20 Hz watchdog calls it), and a
  job is checked again when the lane takes it.
- The failsafe lane (``px4-failsafe``): the deadline HOLD. A pre-empting job withdraws the
  command lane's COMMAND_LONG in flight, and the command lane starts nothing
  new until it is done: a HOLD never queues behind a command (px4_link sends one command at a
  time). Every exception it raises, whatever its type, is counted by type, logged and reported as
  a ``failsafe_failed`` event. Parking a stray OFFBOARD and following PX4 out of OFFBOARD stay on
  the command lane, in order with the commands: run beside a ``land`` they would undo it (the
  watchdog sees OFFBOARD outside a session while the land's mode switch is in flight); their
  failures count and report the same way.

Threads: ``submit*`` and ``expire`` from any thread. A command's future completes on the command
lane or, when abandoned, on the thread that called ``expire``: its done-callbacks must be short.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass, field
from typing import Any

from .events import EventReporter

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had

# Command-lane jobs whose failure is a failed failsafe, not a lifecycle note.
FAILSAFE_JOBS = ("park", "offboard_lost")

CancelCommand = Callable[[int, str], bool]   # px4_link's Px4Link.cancel_command(owner thread, why)


class WorkerBusy(RuntimeError):
    """The command lane already has ``MAX_QUEUED`` commands waiting."""


class CommandAbandoned(RuntimeError):
    """A command's deadline passed: it never starts, or its result is no longer awaited."""


@dataclass
class WorkerCounters:
    commands: int = 0            # commands accepted on the command lane
    busy: int = 0                # refused at once: the lane's queue was full
    expired_queued: int = 0      # deadline passed before they started: they never ran
    expired_running: int = 0     # deadline passed while running: abandoned, PX4 command withdrawn
    preempted: int = 0           # PX4 commands withdrawn for a failsafe
    failsafe_jobs: int = 0
    failsafe_failed: int = 0
    failsafe_errors: Counter[str] = field(default_factory=Counter)   # exception type -> count


@dataclass(eq=False)
class _Job:
    what: str
    fn: Callable[[], Any]
    future: Future[Any]
    deadline: float              # time.monotonic(); inf: lifecycle jobs nobody waits for
    timeout_s: float
    abandoned: bool = False


class Px4Worker:
    MAX_QUEUED = 4               # commands waiting behind the running one; more are refused ("busy")
    MAX_LIFECYCLE = 64           # internal jobs waiting (their sources are bounded: this is a backstop)

    def __init__(self, events: EventReporter, cancel_command: CancelCommand) -> None:
        self._events = events
        self._cancel_command = cancel_command
        self.counters = WorkerCounters()
        self._cond = threading.Condition()
        self._queue: deque[_Job] = deque()
        self._running: _Job | None = None
        self._urgent = 0         # pre-empting failsafe jobs submitted and not finished
        self._closed = False
        self._failsafe_q: queue.SimpleQueue[tuple[str, Callable[[], Any], bool] | None] = queue.SimpleQueue()
        self._command_thread = threading.Thread(target=self._command_loop, name="px4-cmd", daemon=True)
        self._failsafe_thread = threading.Thread(target=self._failsafe_loop, name="px4-failsafe", daemon=True)
        self._command_thread.start()
        self._failsafe_thread.start()

    # -- the command lane ------------------------------------------------------------
    def submit(self, what: str, fn: Callable[[], Any], timeout_s: float) -> Future[Any]:
        """Queue a command; its future fails with CommandAbandoned if it has not finished within
        ``timeout_s``. Raises WorkerBusy at once when ``MAX_QUEUED`` commands already wait."""
        future: Future[Any] = Future()
        with self._cond:
            waiting = sum(1 for j in self._queue if j.deadline != float("inf"))
            if self._closed or waiting >= self.MAX_QUEUED:
                self.counters.busy += 1
                raise WorkerBusy(f"{waiting} PX4 commands already waiting (at most {self.MAX_QUEUED}): "
                                 "try again when they are done")
            self.counters.commands += 1
            self._queue.append(_Job(what, fn, future, time.monotonic() + timeout_s, timeout_s))
            self._cond.notify_all()
        return future

    def submit_guarded(self, what: str, fn: Callable[[], Any]) -> None:
        """A lifecycle job, in order with the commands; nobody waits for it, so a failure is logged
        and reported (a ``lifecycle`` event)."""
        future: Future[Any] = Future()
        with self._cond:
            if self._closed:
                return
            if len(self._queue) >= self.MAX_QUEUED + self.MAX_LIFECYCLE:
                log.error("%s dropped: the PX4 command lane is full", what)
                self._events.event("lifecycle", f"{what} dropped: the PX4 command lane is full", "")
                return
            self._queue.append(_Job(what, lambda: self._guarded(what, fn), future, float("inf"), 0.0))
            self._cond.notify_all()

    def _guarded(self, what: str, fn: Callable[[], Any]) -> None:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001  (nobody reads this job's future: report it here)
            if what in FAILSAFE_JOBS:
                self._failsafe_failed(what, exc)
            else:
                log.error("%s: %s", what, exc)
                self._events.event("lifecycle", f"{what} failed: {exc}", "")

    def _failsafe_failed(self, what: str, exc: Exception) -> None:
        kind = type(exc).__name__
        self.counters.failsafe_failed += 1
        self.counters.failsafe_errors[kind] += 1
        log.error("failsafe %s failed: %s: %s", what, kind, exc, exc_info=not isinstance(exc, RuntimeError))
        self._events.event("failsafe_failed", f"{what} failed: {kind}: {exc}", "")

    def _command_loop(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._queue or self._urgent):
                    self._cond.wait()
                if self._closed:
                    return
                job = self._queue.popleft()
                if job.future.done():   # abandoned while it waited
                    continue
                if time.monotonic() > job.deadline:
                    self._abandon(job, running=False)
                    continue
                if not job.future.set_running_or_notify_cancel():
                    continue
                self._running = job
            try:
                result = job.fn()
            except BaseException as exc:  # noqa: BLE001  (handed to whoever waits on the future)
                self._settle(job.future, exc=exc)
            else:
                self._settle(job.future, result=result)
            finally:
                with self._cond:
                    self._running = None

    @staticmethod
    def _settle(future: Future[Any], result: Any = None, exc: BaseException | None = None) -> None:
        try:
            if exc is not None:
                future.set_exception(exc)
            else:
                future.set_result(result)
        except InvalidStateError:   # abandoned at its deadline: its outcome is no longer awaited
            pass

    def expire(self, now: float) -> None:
        """Abandon the commands whose deadline has passed: waiting ones never start, a running one
        has its PX4 command withdrawn. Any thread (the companion's watchdog, at 20 Hz)."""
        with self._cond:
            stale = [j for j in self._queue if now > j.deadline]
            for job in stale:
                self._queue.remove(job)
            running = self._running
            late = running is not None and now > running.deadline and not running.abandoned
            if late and running is not None:
                running.abandoned = True
        for job in stale:
            self._abandon(job, running=False)
        if late and running is not None:
            self._abandon(running, running=True)

    def _abandon(self, job: _Job, running: bool) -> None:
        if running:
            self.counters.expired_running += 1
            why = (f"{job.what}: no result within {job.timeout_s:g} s: abandoned "
                   "(its PX4 command withdrawn; nothing further is sent for it)")
            self._cancel_command(self._command_ident(), why)
        else:
            self.counters.expired_queued += 1
            why = f"{job.what}: not started within {job.timeout_s:g} s: dropped, it will not run"
        log.warning("%s", why)
        self._settle(job.future, exc=CommandAbandoned(why))

    def _command_ident(self) -> int:
        ident = self._command_thread.ident
        return ident if ident is not None else -1

    # -- the failsafe lane -----------------------------------------------------------
    def submit_failsafe(self, what: str, fn: Callable[[], Any], preempt: bool = False) -> None:
        """Run ``fn`` on the failsafe lane now. ``preempt``: withdraw the command lane's PX4 command
        in flight and hold the lane until ``fn`` is done (a HOLD supersedes any command)."""
        if preempt:
            with self._cond:
                self._urgent += 1
            self._preempt(what)
        self._failsafe_q.put((what, fn, preempt))

    def _preempt(self, what: str) -> None:
        if self._cancel_command(self._command_ident(), f"superseded by the failsafe {what}"):
            self.counters.preempted += 1

    def _failsafe_loop(self) -> None:
        while True:
            item = self._failsafe_q.get()
            if item is None:
                return
            what, fn, preempt = item
            self.counters.failsafe_jobs += 1
            try:
                if preempt:   # again: the command lane's job may have sent a new command meanwhile
                    self._preempt(what)
                fn()
            except Exception as exc:  # noqa: BLE001  (whatever it is, a failed failsafe is reported)
                self._failsafe_failed(what, exc)
            finally:
                if preempt:
                    with self._cond:
                        self._urgent -= 1
                        self._cond.notify_all()

    def summary(self) -> dict[str, Any]:
        c = self.counters
        return {"commands": c.commands, "busy": c.busy, "expired_queued": c.expired_queued,
                "expired_running": c.expired_running, "preempted": c.preempted,
                "failsafe_jobs": c.failsafe_jobs, "failsafe_failed": c.failsafe_failed,
                "failsafe_errors": dict(c.failsafe_errors)}

    def shutdown(self) -> None:
        with self._cond:
            self._closed = True
            pending, self._queue = list(self._queue), deque()
            self._cond.notify_all()
        for job in pending:
            job.future.cancel()
        self._failsafe_q.put(None)
