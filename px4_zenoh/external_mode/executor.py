"""``ModeExecutor``: a PX4 mode executor over Zenoh: arm, take off, the owned mode, RTL, while PX4 keeps it in charge.

What PX4 does with an executor (commander/ModeManagement.cpp, Commander.cpp, PX4 main 2026-03), and how this
class follows it (the sequence is px4-ros2's ModeExecutorBase example: arm, takeoff, the owned mode, rtl,
waitUntilDisarmed):
- the executor is registered together with the mode it owns (``ExternalMode(executor=True)``); PX4 puts it in
  charge when the owned mode is selected (onUserIntendedNavStateChange) and keeps it in charge across mode
  changes it commands itself (source_component 1000+id, ``getSourceFromCommand``); a user's mode change puts
  the autopilot back in charge, and a failsafe makes ``vehicle_status.executor_in_charge`` 0 for as long as it
  lasts (``modeExecutorInCharge``). Either way the sequence stops at once (px4-ros2: onDeactivate) and is not
  resumed behind the user's or the failsafe's back: PX4's failsafes stay in charge.
- its commands go on ``/fmu/in/vehicle_command_mode_executor``; PX4 runs them only while it is in charge
  (``handleCommandsFromModeExecutors``, else TEMPORARILY_REJECTED). This PX4's bridge hands that topic to
  plain ``vehicle_command``, which skips that check (bridge.py): an executor is refused there
  (``ExternalMode(executor=True)`` raises BridgeBugError) unless the bridge is declared fixed.
- a step ends on PX4's ``mode_completed`` for the mode it scheduled (navigator's takeoff, the owned mode's own
  completion), as px4-ros2's ScheduledMode; RTL ends when PX4 disarms after landing (waitUntilDisarmed).
- with an executor in charge PX4 does not switch to Hold after a finished takeoff (Commander.cpp): the
  executor schedules the next mode.

When it starts: on ``request()`` (the companion's offboard_start selected the owned mode: the sequence starts
with arming) or when PX4 shows it in charge and armed after it was not (a user armed in the owned mode, as
px4-ros2's default activation). The owned mode's part ends when the mode reports completion
(``ExternalMode.complete``, e.g. the GCS's ``rtl``), then the executor schedules RTL.

Threading: one daemon thread runs the sequence; ``request``/``close``/properties from any thread.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

from . import messages as m
from .mode import ExternalMode

log = logging.getLogger(__name__)

NAV_TAKEOFF, NAV_RTL = 17, 5          # VehicleStatus NAVIGATION_STATE_AUTO_TAKEOFF, AUTO_RTL
ACCEPTED = 0
IN_CHARGE_WAIT_S = 3.0                # after request(): PX4 shows the executor in charge within a status or two
ARM_WAIT_S = 5.0
TAKEOFF_WAIT_S = 120.0


class Deactivated(Exception):
    """PX4 took the executor out of charge (a failsafe, or a user's mode change)."""


class StepFailed(Exception):
    """PX4 refused or did not answer a step's command."""


class ModeExecutor:
    def __init__(self, mode: ExternalMode, takeoff_amsl_m: float = math.nan,
                 on_step: Callable[[str], None] | None = None) -> None:
        if not mode.executor:
            raise ValueError("ModeExecutor needs an ExternalMode registered with executor=True")
        self.mode = mode
        self.takeoff_amsl_m = takeoff_amsl_m     # NaN: PX4's MIS_TAKEOFF_ALT above the current altitude
        self.on_step = on_step
        self.log: list[tuple[float, str]] = []   # (monotonic time, step or outcome): what a test or summary reads
        self.step = "idle"
        self._requested = threading.Event()
        self._stop = threading.Event()
        self._running = False
        self._thread = threading.Thread(target=self._run, name=f"px4exec-{mode.name}", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        """A sequence is under way and PX4 still has us in charge."""
        return self._running and self.mode.in_charge

    def request(self) -> None:
        """Start the sequence (from arming) once PX4 shows the executor in charge."""
        self._requested.set()

    def close(self) -> None:
        self._stop.set()
        self._requested.set()
        self._thread.join(3.0)

    # ---------------------------------------------------------------- the thread
    def _record(self, what: str) -> None:
        self.log.append((time.monotonic(), what))
        log.info("px4 executor %r: %s", self.mode.name, what)
        if self.on_step is not None:
            self.on_step(what)

    def _run(self) -> None:
        was = False
        while not self._stop.is_set():
            if self._requested.wait(0.05):
                self._requested.clear()
                if self._stop.is_set():
                    return
                if not self.mode.wait(lambda: self.mode.in_charge or self._stop.is_set(), IN_CHARGE_WAIT_S) \
                        or self._stop.is_set():
                    self._record("not started: PX4 does not show the executor in charge")
                    continue
                self._sequence()
            now = self.mode.in_charge and self.mode.armed
            if now and not was:          # a user armed in the owned mode: px4-ros2's default activation
                self._sequence()
                now = self.mode.in_charge and self.mode.armed
            was = now

    def _sequence(self) -> None:
        self._running = True
        try:
            self._record("activated")
            self._arm()
            self._scheduled("takeoff", NAV_TAKEOFF, m.CMD_NAV_TAKEOFF,
                            (math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, self.takeoff_amsl_m),
                            TAKEOFF_WAIT_S)
            own = self.mode.mode_id
            self._scheduled("mode", own, m.CMD_SET_NAV_STATE, (float(own),), None)
            self._set_step("rtl")
            self._command(m.CMD_SET_NAV_STATE, float(NAV_RTL))
            self._until(lambda: not self.mode.armed, None)          # waitUntilDisarmed
            self._record("done: landed and disarmed")
        except Deactivated:
            self._record("deactivated: " + ("failsafe" if self.mode.failsafe else "PX4 put the autopilot in charge"))
        except StepFailed as e:
            self._record(f"aborted: {e}")
        finally:
            self._running = False
            self.step = "idle"

    def _set_step(self, step: str) -> None:
        self.step = step
        self._record(step)

    def _arm(self) -> None:
        self._set_step("arm")
        if self.mode.armed:
            return
        self._command(m.CMD_ARM_DISARM, 1.0)
        self._until(lambda: self.mode.armed, ARM_WAIT_S)

    def _scheduled(self, step: str, nav: int, command: int, params: tuple[float, ...], timeout_s: float | None) -> None:
        """Send the step's command and wait for PX4's mode_completed of ``nav`` (px4-ros2 scheduleMode)."""
        self._set_step(step)
        since = time.monotonic()
        self._command(command, *params)
        self._until(lambda: any(n == nav for _, n, _r in self.mode.completions(since)), timeout_s)
        results = [r for _, n, r in self.mode.completions(since) if n == nav]
        if results and results[-1] != m.RESULT_SUCCESS:
            raise StepFailed(f"{step}: mode {nav} completed with result {results[-1]}")

    def _command(self, command: int, *params: float) -> None:
        if not self.mode.in_charge:
            raise Deactivated
        result = self.mode.executor_command(command, *params)
        if result is None:
            raise StepFailed(f"command {command}: no answer from PX4")
        if result != ACCEPTED:
            if not self.mode.in_charge:
                raise Deactivated
            raise StepFailed(f"command {command}: PX4 answered {result}")

    def _until(self, done: Callable[[], bool], timeout_s: float | None) -> None:
        deadline = math.inf if timeout_s is None else time.monotonic() + timeout_s
        while not done():
            if self._stop.is_set():
                raise StepFailed("executor closed")
            if not self.mode.in_charge:
                raise Deactivated
            if time.monotonic() > deadline:
                raise StepFailed(f"{self.step}: not done within {timeout_s:g} s")
            self.mode.wait(lambda: done() or not self.mode.in_charge or self._stop.is_set(), 0.2)
