"""The link-loss failsafe: setpoints from the controller stop for ``setpoint_deadline`` while a
session is active -> HOLD (AUTO.LOITER), then the stream stops, and a FailsafeEvent says so.

Two triggers, so the failsafe never depends on one mechanism alone: the setpoint subscription's
QoS deadline event (``on_deadline_missed``, on the node's executor) and the companion's 20 Hz
watchdog (``check``, a timer on the same executor). They may race on a multi-threaded executor:
a lock makes one of them win. The HOLD itself runs on the PX4 worker.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from px4_link.commands import CommandError

from .control import ControlArbiter
from .events import EventReporter
from .offboard_session import OffboardLifecycle, OffboardState
from .px4_worker import Px4Worker

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had


class DeadlineFailsafe:
    def __init__(self, lifecycle: OffboardLifecycle, control: ControlArbiter, events: EventReporter,
                 worker: Px4Worker, deadline_s: Callable[[], float]) -> None:
        self._lifecycle, self._control, self._events, self._worker = lifecycle, control, events, worker
        self._deadline_s = deadline_s     # live: a `param set` changes it
        self.reason = ""                  # why we hold, or ""
        self.last_setpoint_at = 0.0       # last setpoint forwarded to PX4 inside a session
        self._lock = threading.Lock()

    def fed(self, now: float) -> None:
        """A setpoint reached PX4's stream: only those keep the failsafe away (garbage is no link)."""
        self.last_setpoint_at = now

    def rearm(self) -> None:
        """A session (re)started: the deadline counts from now."""
        self.last_setpoint_at = time.monotonic()
        self.reason = ""

    def clear(self) -> None:
        self.reason = ""

    def check(self, now: float) -> None:
        """The watchdog's backstop for the QoS deadline event."""
        if self._lifecycle.state is OffboardState.ACTIVE and now - self.last_setpoint_at > self._deadline_s():
            self.on_deadline_missed(None)

    def on_deadline_missed(self, status: Any) -> None:
        with self._lock:
            if self._lifecycle.state is not OffboardState.ACTIVE or self.reason:
                return
            self.reason = f"no setpoint for {self._deadline_s():.1f} s"
        self._events.event("setpoint_deadline_missed", self.reason, "HOLD", self._control.holder)
        self._worker.submit(self._hold, self.reason)

    def _hold(self, why: str) -> None:
        try:
            self._lifecycle.deadline_missed(why)   # HOLD first, then stop streaming
        except CommandError as exc:
            log.error("failsafe HOLD failed: %s", exc)
            self._events.event("failsafe_failed", str(exc), "")
