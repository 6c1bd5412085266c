"""The simulator's commander with PX4's external modes: px4_link.sim's Commander plus ModeManagement.

One job: put ``mode_management.ModeManagement`` where PX4's commander puts it. Modes EXTERNAL1..8
(nav_state 23..30) are modes like any other here: selectable by VEHICLE_CMD_SET_NAV_STATE (100001, the
px4-ros2 way) or DO_SET_MODE with PX4's custom mode main 4 (AUTO), sub 11..18 (px4_custom_mode.h
PX4_CUSTOM_SUB_MODE_EXTERNAL1..8, Commander.cpp handle_command), flown from the component's
trajectory_setpoint / goto_setpoint while selected.

What follows PX4 (file, function):
- the 10 Hz health checks read the external checks' report (Commander.cpp run: checks at 10 Hz or on
  change; externalChecks.cpp checkAndReport): a mode that is not registered, unresponsive, or whose
  reply says can_arm_and_run false cannot run and cannot be armed into; a failing replacement also
  blocks the internal mode it replaces; a mode-less registration's false refuses arming in every mode.
- selecting a mode (UserModeIntention.cpp change): a replacement is selected as the internal mode it
  replaces; always accepted disarmed, armed only if it can run; the flown nav_state is the internal
  mode's responsive replacement (Commander.cpp: nav_state = getNavStateReplacementIfValid(...)).
- armed in an external mode that can no longer run: failsafe/failsafe.cpp checkModeFallback -> RTL
  (itself replaced if a responsive replacement of RTL exists), Land when RTL cannot run either
  (framework.cpp action fallthrough); back to the mode once it can run again. An unresponsive
  replacement falls back to the internal mode without a failsafe (getNavStateReplacementIfValid).
- disarm (ModeManagement::onDisarm): the executor's owned mode if one is in charge, Hold if that mode
  is unresponsive.
- executor in charge (onUserIntendedNavStateChange): a user's mode change puts the autopilot back in
  charge; a change from a mode executor (source component >= 1000) keeps the executor in charge.
- mode_completed (navigator_main.cpp mode_completed, which px4-ros2 executors wait for): takeoff.cpp when the
  takeoff point is reached, land.cpp and rtl_direct.cpp (RTLState::IDLE after its land) when landed; queued in
  ``completions`` for the simulator to publish.
- takeoff complete with a mode executor in charge: no switch to Hold (Commander.cpp: the auto-Loiter after a
  finished takeoff only while the autopilot is in charge); the vehicle holds the takeoff point until the
  executor schedules its next mode.
- setpoints: PX4's position controller flies the latest trajectory_setpoint in an external mode (no
  offboard_control_mode needed); a goto_setpoint counts for 500 ms (FlightModeManager's goto timeout),
  then the vehicle holds. Setpoints sent while neither an external mode nor OFFBOARD is flown would fight
  PX4's own flight tasks on the same uORB topic: counted (``setpoints_outside_mode``; OFFBOARD's pre-stream
  before the switch counts too) and ignored.

Threading: as Commander, under its lock, on the simulator's loop thread.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from px4_link.sim.commander import (
    ACCEPTED,
    ON_GROUND,
    TEMPORARILY_REJECTED,
    USER_REASONS,
    Commander,
    CommandResult,
    int_param,
)
from px4_link.sim.physics import Target

from .mode_management import AUTOPILOT_EXECUTOR_ID, FIRST_EXTERNAL_NAV_STATE, ModeManagement, is_external
from .uorb_out import NAV_STATE, nav_state

CMD_SET_NAV_STATE = 100001          # VehicleCommand VEHICLE_CMD_SET_NAV_STATE
MAIN_AUTO = 4
SUB_EXTERNAL1 = 11                  # px4_custom_mode.h PX4_CUSTOM_SUB_MODE_EXTERNAL1
CHECKS_PERIOD_S = 0.1               # Commander.cpp: health and arming checks at 10 Hz
GOTO_TIMEOUT_S = 0.5                # FlightModeManager: a goto_setpoint older than this is not flown
MODE_BY_NAV = {v: k for k, v in NAV_STATE.items()}


def ext_mode(nav: int) -> str:
    return MODE_BY_NAV.get(nav, f"NAV{nav}")


@dataclass
class ExtCommander(Commander):
    mm: ModeManagement = field(default_factory=ModeManagement)
    command_from_executor: bool = False    # the command being handled came from a mode executor
    setpoints_outside_mode: int = 0
    completions: list[int] = field(default_factory=list)   # nav_states whose mode_completed is due out

    def __post_init__(self) -> None:
        super().__post_init__()
        self.user_intention = self.mode
        self._checks_at = -math.inf
        self._ext_target: Target | None = None
        self._goto_at: float | None = None
        self._ext_fallback: str | None = None   # the external mode a failsafe left
        self._completed_reported = False        # this mode's mode_completed sent (once per entry, as navigator)

    # ------------------------------------------------------------ modes
    def _set_mode(self, new: str, reason: str) -> None:
        base = self.mm.replaced_mode_if_any(nav_state(new))
        if reason in USER_REASONS or reason.startswith("disarmed"):
            if reason in USER_REASONS:
                self.mm.on_user_intention_change(self.command_from_executor, base)
            self.user_intention = ext_mode(base)
        super()._set_mode(ext_mode(self.mm.replacement_if_valid(base)), reason)

    def _enter(self, mode: str) -> None:
        self._completed_reported = False
        if is_external(nav_state(mode)):
            self._ext_target, self._goto_at = None, None
            self._hold_pos, self._hold_yaw = self.vehicle.pos.copy(), self.vehicle.yaw
            return
        super()._enter(mode)

    def _can_run(self, mode: str) -> str | None:
        nav, report = nav_state(mode), self.mm.report
        why = report.cannot_run.get(nav)
        if why is not None:
            return why
        if is_external(nav):
            if nav in report.requires_position and not self.estimate_valid():
                return "No valid position estimate"
            return None
        return super()._can_run(mode)

    def _mode_arming_refusal(self) -> str | None:
        refusal = super()._mode_arming_refusal()
        if refusal is not None:
            return refusal
        report = self.mm.report
        if report.cannot_arm_any is not None:
            return f"Arming denied: {report.cannot_arm_any}"
        why = report.cannot_arm.get(nav_state(self.mode))
        return None if why is None else f"Arming denied: {why}"

    def _request_mode(self, mode: str, reason: str) -> CommandResult:
        base = ext_mode(self.mm.replaced_mode_if_any(nav_state(mode)))
        if not is_external(nav_state(base)):
            return super()._request_mode(base, reason)
        if self.mode == "TERMINATION":
            return CommandResult(TEMPORARILY_REJECTED, f"{base} rejected: in TERMINATION")
        why = self._can_run(base) if self.armed else None
        if why is not None:
            return CommandResult(TEMPORARILY_REJECTED, f"{base} rejected: {why}")
        self._set_mode(base, reason)
        return CommandResult(ACCEPTED)

    def _do_set_mode(self, p: list[float]) -> CommandResult:
        base_mode, main, sub = int_param(p[0]), int_param(p[1]), int_param(p[2])
        if base_mode & 1 and main == MAIN_AUTO and SUB_EXTERNAL1 <= sub < SUB_EXTERNAL1 + 8:
            return self._request_mode(ext_mode(FIRST_EXTERNAL_NAV_STATE + sub - SUB_EXTERNAL1), "command")
        return super()._do_set_mode(p)

    def handle_command(self, command: int, p: list[float], now: float | None = None) -> CommandResult:
        if command != CMD_SET_NAV_STATE:
            return super().handle_command(command, p, now)
        with self._lock:
            if now is not None:
                self.now = now
            nav = int(round(p[0])) if math.isfinite(p[0]) else -1
            if nav not in MODE_BY_NAV:
                return CommandResult(TEMPORARILY_REJECTED, f"nav_state {nav} unknown")
            return self._request_mode(MODE_BY_NAV[nav], "command")

    def _disarm(self, reason: str) -> None:
        stored = self._mode_after_disarm
        self._mode_after_disarm = ext_mode(self.mm.on_disarm(nav_state(stored)))
        self._ext_fallback = None
        try:
            super()._disarm(reason)
        finally:
            self._mode_after_disarm = stored

    # ------------------------------------------------------------ the commander cycle
    def update(self, now: float) -> Target | None:
        with self._lock:
            self.now = now
            intention = nav_state(self.user_intention)
            req = self.mm.update(now, self.armed, self.mm.replacement_if_valid(intention, False))
            if req.change_user_intended_nav_state and not self.armed:   # Commander::modeManagementUpdate
                self.command_from_executor = False
                self._request_mode(ext_mode(req.user_intended_nav_state), "command")
            if now >= self._checks_at + CHECKS_PERIOD_S:
                self._checks_at = now
                self.mm.check_and_report()
            self._check_external()
            self.mm.failsafe_action_active = self.failsafe
            target = super().update(now)
            if self.mode in ("AUTO.RTL", "AUTO.LAND") and self.landed_state == ON_GROUND:
                self._complete(self.mode)     # land.cpp / rtl_direct.cpp: landed -> mode_completed
            return target

    def _complete(self, mode: str) -> None:
        if not self._completed_reported:
            self._completed_reported = True
            self.completions.append(nav_state(mode))

    def _fallback_mode(self) -> str:
        return "AUTO.RTL" if self._can_run("AUTO.RTL") is None else "AUTO.LAND"

    def _check_external(self) -> None:
        if not self.armed:
            return
        nav = nav_state(self.mode)
        base = self.mm.replaced_mode_if_any(nav)
        if is_external(nav) and base != nav:                         # flying a replacement
            if self.mm.is_unresponsive(nav):
                self._set_mode(ext_mode(base), "fallback: replacement unresponsive")
            elif self._can_run(self.mode) is not None:
                self._ext_fallback = ext_mode(base)   # back to it (so to the replacement) once it can run
                self.failsafe_action("external mode", self._fallback_mode(),
                                     f"Failsafe: {self.mode} cannot run ({self._can_run(self.mode)})")
            return
        if is_external(nav) and self._ext_fallback is None:
            why = self._can_run(self.mode)
            if why is not None:
                self._ext_fallback = self.mode
                self.failsafe_action("external mode", self._fallback_mode(),
                                     f"Failsafe: {self.mode} {why}")
            return
        if self._ext_fallback is not None:
            if not self.failsafe or self.user_intention != self._ext_fallback:
                self._ext_fallback = None
            elif self._can_run(self._ext_fallback) is None:
                mode, self._ext_fallback = self._ext_fallback, None
                self.restore_mode(mode, "failsafe cleared: external mode can run")
            return
        if not is_external(nav) and self.mm.replacement_if_valid(nav, False) != nav:
            self._set_mode(self.mode, "replacement available")     # an internal mode got a replacement

    # ------------------------------------------------------------ setpoints
    def on_external_setpoint(self, position: tuple[float, float, float] | None,
                             velocity: tuple[float, float, float] | None, yaw: float | None,
                             goto: bool) -> bool:
        """A trajectory_setpoint (goto False) or goto_setpoint; True if it is flown."""
        with self._lock:
            if not is_external(nav_state(self.mode)):
                if self.mode != "OFFBOARD":
                    self.setpoints_outside_mode += 1
                return False
            pos = np.array(position) if position is not None else None
            vel = np.array(velocity) if velocity is not None else None
            if pos is None and vel is None:
                pos = self.vehicle.pos.copy()
            self._ext_target = Target(position=pos, velocity=vel, yaw=yaw)
            self._goto_at = self.now if goto else None
            return True

    def _mode_target(self) -> Target | None:
        if self.mode == "AUTO.TAKEOFF":
            v = self.vehicle
            if abs(v.pos[2] - self._hold_pos[2]) < max(0.1 * self._takeoff_alt, 0.2):   # as the base's test
                self._complete(self.mode)                   # takeoff.cpp: the takeoff point reached
                if self.mm.executor_in_charge() != AUTOPILOT_EXECUTOR_ID:
                    return Target(position=self._hold_pos, yaw=self._hold_yaw)   # no auto-Hold: the executor's
        if not is_external(nav_state(self.mode)):
            return super()._mode_target()
        t = self._ext_target
        if t is not None and self._goto_at is not None and self.now - self._goto_at > GOTO_TIMEOUT_S:
            self._hold_pos, self._hold_yaw = self.vehicle.pos.copy(), self.vehicle.yaw
            self._ext_target = t = None
        if t is None:
            if self.landed_state == ON_GROUND:
                v = self.vehicle
                return Target(position=np.array([v.pos[0], v.pos[1], 0.0]), yaw=self._hold_yaw)
            return Target(position=self._hold_pos, yaw=self._hold_yaw)
        return Target(position=t.position, velocity=t.velocity, yaw=t.yaw)

