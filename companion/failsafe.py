"""The link-loss failsafe: setpoints from the controller stop for ``setpoint_deadline`` while a
session is active -> HOLD (AUTO.LOITER), then the stream stops, and a FailsafeEvent says so.

Two triggers, so the failsafe never depends on one mechanism alone: the setpoint subscription's
QoS deadline event (``on_deadline_missed``, on the node's executor) and the companion's 20 Hz
watchdog (``check``, a timer on the same executor). They may race on a multi-threaded executor:
a lock makes one of them win. The HOLD runs on the PX4 worker's failsafe lane, never behind a
command: it withdraws the PX4 command in flight, first freezes px4_link's target where the
vehicle is (a last velocity setpoint would keep the drone moving until PX4 switches), then
commands HOLD and stops the stream. Any exception there is counted and reported by the lane
(``failsafe_failed``).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from px4_link.targets import PositionTarget, TargetRefused

from .control import ControlArbiter
from .events import EventReporter
from .offboard_session import OffboardLifecycle, OffboardState
from .px4_worker import Px4Worker

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had

Position = Callable[[], "tuple[float, float, float] | None"]   # the vehicle's local NED position, if fresh


class DeadlineFailsafe:
    LATENCIES_KEPT = 32

    def __init__(self, lifecycle: OffboardLifecycle, control: ControlArbiter, events: EventReporter,
                 worker: Px4Worker, deadline_s: Callable[[], float], position: Position) -> None:
        self._lifecycle, self._control, self._events, self._worker = lifecycle, control, events, worker
        self._deadline_s = deadline_s     # live: a `param set` changes it
        self._position = position
        self.reason = ""                  # why we hold, or ""
        self.last_setpoint_at = 0.0       # last setpoint forwarded to PX4 inside a session
        self.triggered = 0
        self.holds = 0                    # HOLDs PX4 confirmed
        # trigger -> HOLD confirmed by PX4's heartbeat (s), the latest ones (the heartbeat comes at
        # ~1 Hz, so this is an upper bound of when PX4 switched)
        self.hold_confirmed_s: deque[float] = deque(maxlen=self.LATENCIES_KEPT)
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
            self.reason = why = f"no setpoint for {self._deadline_s():.1f} s"
            self.triggered += 1
        since = time.monotonic()
        self._worker.submit_failsafe("HOLD", lambda: self._hold(why, since), preempt=True)   # first: never wait
        self._events.event("setpoint_deadline_missed", why, "HOLD", self._control.holder)

    def _hold(self, why: str, since: float) -> None:
        """The failsafe lane. Exceptions propagate to the lane, which counts and reports them."""
        self._freeze()
        if self._lifecycle.deadline_missed(why):   # HOLD first, then stop streaming
            self.holds += 1
            self.hold_confirmed_s.append(time.monotonic() - since)

    def _freeze(self) -> None:
        pos = self._position()
        if pos is None:
            return
        try:
            self._lifecycle.forward(PositionTarget(*pos, None))
        except TargetRefused as exc:   # no session any more, or outside the fence: HOLD goes anyway
            log.warning("failsafe: could not freeze the target at %s: %s", pos, exc)

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.hold_confirmed_s)
        return {"triggered": self.triggered, "holds": self.holds,
                "hold_confirmed_s": {"last": round(self.hold_confirmed_s[-1], 4), "max": round(lat[-1], 4),
                                   "median": round(lat[len(lat) // 2], 4)} if lat else {}}
