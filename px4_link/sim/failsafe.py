"""PX4's failsafe triggers and actions, with PX4's parameters (beyond offboard loss, which the
commander checks itself through ``offboard_loss_action``).

Each rule follows PX4-Autopilot's source (main of 2026-03), cited where it is applied:
- the action tables: src/modules/commander/failsafe/failsafe.cpp (fromGfActParam,
  fromNavDllOrRclActParam, fromBatteryWarningActParam, fromOffboardLossActParam, checkModeFallback);
- the hold before an action (COM_FAIL_ACT_T), the mode fallbacks (RTL -> Land -> Descend) and
  "already landing / returning: only warn": src/modules/commander/failsafe/framework.cpp;
- geofence: src/modules/navigator/geofence.cpp (GF_MAX_HOR_DIST / GF_MAX_VER_DIST from home, 0 = off)
  and src/modules/commander/HealthAndArmingChecks/checks/geofenceCheck.cpp (texts);
- battery levels: src/lib/battery/battery.cpp (determineWarning) and
  src/modules/commander/HealthAndArmingChecks/checks/batteryCheck.cpp (texts);
- GCS link: src/modules/mavlink/mavlink_receiver.cpp (only MAV_TYPE_GCS heartbeats count, from any
  system; checked every 1.25 s with a 2.5 s timeout) and src/modules/commander/Commander.cpp
  (COM_DL_LOSS_T after the last check that saw one), checks/rcAndDataLinkCheck.cpp (arming);
- RC loss: failsafe.cpp checkStateAndMode: RC lost at arming is ignored for that flight, so in a
  simulator without RC it never fires; NAV_RCL_ACT is then only the fallback of the offboard loss;
- estimate loss: checks/offboardCheck.cpp (position offboard needs a valid local position) and
  src/modules/commander/ModeUtil/mode_requirements.cpp (Hold, RTL, Land need a position; Descend only
  attitude), so the fallback chain ends in Descend, which PX4 reports as AUTO.LAND
  (px4_custom_mode.h).

Threading: everything runs on the simulator's loop thread under its lock, except ``on_heartbeat``,
which the protocol calls from the same loop.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .params import ParamStore

# Actions, in PX4's order of precedence (framework.h Action).
NONE, WARN, HOLD, RTL, LAND, DESCEND, DISARM, TERMINATE = (
    "none", "warn", "hold", "rtl", "land", "descend", "disarm", "terminate")
# The mode each action puts the vehicle in; DISARM / TERMINATION are handled by the commander.
ACTION_MODES = {HOLD: "AUTO.LOITER", RTL: "AUTO.RTL", LAND: "AUTO.LAND", DESCEND: "AUTO.LAND",
                TERMINATE: "TERMINATION", DISARM: "DISARM"}
# framework.cpp getSelectedAction: only these are preceded by COM_FAIL_ACT_T of Hold, and only for
# options that allow user takeover "Auto" (the default; not the mode fallbacks, nor a geofence Hold).
DELAYABLE = frozenset({RTL, LAND, DESCEND})

# battery_status_s::WARNING_*
WARNING_NONE, WARNING_LOW, WARNING_CRITICAL, WARNING_EMERGENCY = 0, 1, 2, 3
MAV_TYPE_GCS = 6
HEARTBEAT_TIMEOUT_S = 2.5   # telemetry_status HEARTBEAT_TIMEOUT_US
HEARTBEAT_CHECK_S = HEARTBEAT_TIMEOUT_S / 2   # MavlinkReceiver::CheckHeartbeats period
ON_GROUND = 1   # MAV_LANDED_STATE_ON_GROUND
# COM_DLL_EXCEPT / COM_RCL_EXCEPT bits (failsafe.cpp isFailsafeIgnored)
EXCEPT_MISSION, EXCEPT_AUTO, EXCEPT_OFFBOARD = 1, 2, 4
AUTO_MODES = frozenset({"AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LAND", "AUTO.RTL", "AUTO.PRECLAND"})
# Modes that cannot run without a position estimate (mode_requirements.cpp; offboardCheck.cpp).
NEEDS_POSITION = frozenset({"OFFBOARD", "AUTO.LOITER", "AUTO.RTL", "AUTO.TAKEOFF", "AUTO.LAND",
                            "AUTO.MISSION", "POSCTL"})


def dll_rcl_action(value: int) -> str:
    """NAV_DLL_ACT / NAV_RCL_ACT -> action (failsafe.cpp fromNavDllOrRclActParam)."""
    return {1: HOLD, 2: RTL, 3: LAND, 5: TERMINATE, 6: DISARM}.get(value, NONE)


def gf_action(value: int) -> str:
    """GF_ACTION -> action (failsafe.cpp fromGfActParam; unknown values warn)."""
    return {0: NONE, 1: WARN, 2: HOLD, 3: RTL, 4: TERMINATE, 5: LAND}.get(value, WARN)


def battery_action(com_low_bat_act: int, warning: int) -> str:
    """COM_LOW_BAT_ACT and the battery warning -> action (failsafe.cpp fromBatteryWarningActParam):
    low only warns; critical: 2 land, 3 return; emergency: 2 and 3 land."""
    if warning == WARNING_CRITICAL:
        return {2: LAND, 3: RTL}.get(com_low_bat_act, WARN)
    if warning == WARNING_EMERGENCY:
        return {2: LAND, 3: LAND}.get(com_low_bat_act, WARN)
    return WARN if warning == WARNING_LOW else NONE


def battery_warning(remaining: float, params: ParamStore) -> int:
    """lib/battery/battery.cpp determineWarning: strict "below" each threshold."""
    if remaining < float(params["BAT_EMERGEN_THR"]):
        return WARNING_EMERGENCY
    if remaining < float(params["BAT_CRIT_THR"]):
        return WARNING_CRITICAL
    if remaining < float(params["BAT_LOW_THR"]):
        return WARNING_LOW
    return WARNING_NONE


def offboard_loss_action(params: ParamStore) -> str:
    """The mode PX4 switches to when the offboard signal is lost (failsafe.cpp checkModeFallback):
    COM_OBL_RC_ACT, where Position/Altitude/Stabilized (0-2) need manual control; the simulator has
    none, so those fall back to NAV_RCL_ACT (SITL default 2: Return, as in the Zenoh trace)."""
    obl = int(params["COM_OBL_RC_ACT"])
    table = {3: "AUTO.RTL", 4: "AUTO.LAND", 5: "AUTO.LOITER", 6: "TERMINATION", 7: "DISARM"}
    if obl in table:
        return table[obl]
    action = dll_rcl_action(int(params["NAV_RCL_ACT"]))
    return ACTION_MODES.get(action, "AUTO.RTL")


def link_loss_ignored(mode: str, except_mask: int) -> bool:
    """failsafe.cpp isFailsafeIgnored: COM_DLL_EXCEPT / COM_RCL_EXCEPT exempt some modes."""
    if mode == "AUTO.MISSION":
        return bool(except_mask & EXCEPT_MISSION)
    if mode in AUTO_MODES:
        return bool(except_mask & EXCEPT_AUTO)
    if mode == "OFFBOARD":
        return bool(except_mask & EXCEPT_OFFBOARD)
    return False


class Vehicle(Protocol):
    """What the failsafe reads from and does to the commander."""
    mode: str
    armed: bool
    landed_state: int

    def failsafe_action(self, cause: str, mode: str, text: str, delay_s: float = 0.0) -> None: ...
    def say(self, text: str, severity: int = 4) -> None: ...
    def offboard_signal_ok(self) -> bool: ...
    def estimate_valid(self) -> bool: ...
    def restore_mode(self, mode: str, reason: str) -> None: ...


@dataclass(slots=True)
class _Edge:
    """A failsafe condition's last state: PX4 acts on the rising edge (framework.cpp checkFailsafe)
    and keeps the action until the condition clears (ClearCondition::OnModeChangeOrDisarm)."""
    active: bool = False


class Failsafes:
    """Geofence, battery, GCS link and estimate-loss failsafes of one simulated PX4."""

    def __init__(self, params: ParamStore, vehicle: Vehicle) -> None:
        self.params = params
        self.vehicle = vehicle
        self.gcs_connection_lost = True          # Commander.cpp: true from boot until a GCS is heard
        self._gcs_heartbeat: float | None = None
        self._gcs_last_seen: float | None = None  # Commander's _datalink_last_heartbeat_gcs
        self._next_hb_check: float | None = None
        self._dll = _Edge()
        self._fence = _Edge()
        self._battery_warning = WARNING_NONE
        self._battery_warning_at_arming = WARNING_NONE
        self._was_armed = False
        self._estimate_fallback_from: str | None = None

    # ------------------------------------------------------------ inputs
    def on_heartbeat(self, mav_type: int, sysid: int, now: float) -> None:
        """mavlink_receiver.cpp handle_message_heartbeat: a GCS counts from any system id; the
        companion's MAV_TYPE_ONBOARD_CONTROLLER heartbeats are not a data link."""
        if mav_type == MAV_TYPE_GCS:
            self._gcs_heartbeat = now

    def arming_refusal(self) -> str | None:
        """rcAndDataLinkCheck.cpp: with NAV_DLL_ACT set, arming needs a GCS connection; geofenceCheck.cpp:
        not outside the fence. None when these checks pass."""
        if int(self.params["NAV_DLL_ACT"]) > 0 and self.gcs_connection_lost:
            return "Preflight Fail: No connection to the GCS"
        return None

    # ------------------------------------------------------------ periodic
    def update(self, now: float, position: np.ndarray, battery_remaining: float) -> None:
        v = self.vehicle
        if v.armed and not self._was_armed:   # failsafe.cpp updateArmingState
            self._battery_warning_at_arming = self._battery_warning
        self._was_armed = v.armed
        self._check_gcs_link(now)
        self._check_estimate()
        self._check_geofence(position)
        self._check_battery(battery_remaining)

    def _flying(self) -> bool:
        return self.vehicle.armed and self.vehicle.landed_state != ON_GROUND

    def _act(self, cause: str, action: str, text: str, *, delayable: bool = True) -> None:
        """Apply ``action`` as framework.cpp getSelectedAction does: warnings only warn; while already
        landing (or returning) a Return (Return or Land) only warns; RTL/Land are preceded by
        COM_FAIL_ACT_T of Hold when the option allows takeover "Auto" and Hold can run."""
        v = self.vehicle
        if action in (NONE, WARN):
            return
        if not v.armed:   # getSelectedAction: no action while disarmed
            return
        if v.mode == "AUTO.LAND" and action in (RTL, LAND):
            v.say(f"Failsafe: {cause}, already landing", 4)
            return
        if v.mode == "AUTO.RTL" and action == RTL:
            v.say(f"Failsafe: {cause}, already returning", 4)
            return
        delay = float(self.params["COM_FAIL_ACT_T"])
        # clearDelayIfNeeded: no Hold delay where Hold cannot run (no position estimate)
        if not delayable or action not in DELAYABLE or delay <= 0.1 or not v.estimate_valid():
            delay = 0.0
        mode = ACTION_MODES[action]
        v.failsafe_action(cause, mode, text if delay == 0.0
                          else f"Failsafe activated: entering Hold for {int(delay + 0.5)} seconds", delay)

    def _check_gcs_link(self, now: float) -> None:
        # MavlinkReceiver::CheckHeartbeats: every 1.25 s, "a GCS heartbeat within 2.5 s".
        if self._next_hb_check is None:
            self._next_hb_check = now
        if now >= self._next_hb_check:
            self._next_hb_check = now + HEARTBEAT_CHECK_S
            hb = self._gcs_heartbeat
            if hb is not None and now <= hb + HEARTBEAT_TIMEOUT_S:
                if self.gcs_connection_lost:
                    self.gcs_connection_lost = False
                    self._dll.active = False
                    if self._gcs_last_seen is not None:
                        self.vehicle.say("GCS connection regained", 6)
                self._gcs_last_seen = now
        # Commander.cpp: lost once no check saw a GCS for COM_DL_LOSS_T.
        seen = self._gcs_last_seen
        if not self.gcs_connection_lost and seen is not None \
                and now - seen > float(self.params["COM_DL_LOSS_T"]):
            self.gcs_connection_lost = True
            self.vehicle.say("Connection to ground station lost", 6)
        # failsafe.cpp checkStateAndMode: NAV_DLL_ACT, not while landing, COM_DLL_EXCEPT.
        lost = self.gcs_connection_lost and seen is not None
        act = int(self.params["NAV_DLL_ACT"])
        mode = self.vehicle.mode
        ignored = mode in ("AUTO.LAND", "AUTO.PRECLAND") or link_loss_ignored(mode, int(self.params["COM_DLL_EXCEPT"]))
        if lost and act != 0 and not ignored and not self._dll.active and self._flying():
            self._dll.active = True
            self._act("GCS connection loss", dll_rcl_action(act), "Failsafe activated")
        if not lost:
            self._dll.active = False

    def _check_estimate(self) -> None:
        v = self.vehicle
        if not v.estimate_valid():
            if self._estimate_fallback_from is None and self._flying() and v.mode in NEEDS_POSITION:
                # checkModeFallback: the intended mode cannot run -> RTL -> Land -> Descend (all need a
                # position but Descend); a mode fallback allows takeover "Always": no Hold delay.
                self._estimate_fallback_from = v.mode
                v.failsafe_action("estimate loss", ACTION_MODES[DESCEND],
                                  "Failsafe activated: Autopilot disengaged, switching to Descend")
            return
        was = self._estimate_fallback_from
        if was is None:
            return
        self._estimate_fallback_from = None
        # The fallback clears with its condition (ClearCondition::WhenConditionClears): PX4 returns to
        # the user's intended mode if it can run; OFFBOARD without a signal takes the offboard loss path.
        if not v.armed or v.landed_state == ON_GROUND or v.mode != "AUTO.LAND":
            return
        if was == "OFFBOARD" and not v.offboard_signal_ok():
            v.failsafe_action("offboard loss", offboard_loss_action(self.params), "Failsafe activated")
        else:
            v.restore_mode(was, "failsafe cleared: estimate valid")

    def _check_geofence(self, pos: np.ndarray) -> None:
        # navigator/geofence.cpp: outside when the distance from home reaches the limit (> 0 = on).
        hor, ver = float(self.params["GF_MAX_HOR_DIST"]), float(self.params["GF_MAX_VER_DIST"])
        too_far = hor > 0 and math.hypot(float(pos[0]), float(pos[1])) >= hor
        too_high = ver > 0 and -float(pos[2]) >= ver
        breached = (too_far or too_high) and self.vehicle.armed
        action = gf_action(int(self.params["GF_ACTION"]))
        if breached and not self._fence.active and action != NONE:
            self._fence.active = True
            # geofenceCheck.cpp: mavlink_log_critical per limit
            if too_far:
                self.vehicle.say("Geofence: exceeding maximum distance to Home", 2)
            if too_high:
                self.vehicle.say("Geofence: exceeding maximum altitude above Home", 2)
            # fromGfActParam: Hold allows takeover by mode switch only -> never delayed
            self._act("geofence breach", action, "Failsafe activated", delayable=action != HOLD)
        elif not breached:
            self._fence.active = False

    def _check_battery(self, remaining: float) -> None:
        warning = battery_warning(remaining, self.params)
        if warning == self._battery_warning:
            return
        worse = warning > self._battery_warning
        self._battery_warning = warning
        if not worse:
            return
        text = {WARNING_LOW: "Low battery", WARNING_CRITICAL: "Critical battery",
                WARNING_EMERGENCY: "Emergency battery level"}[warning]
        self.vehicle.say(text, 0 if warning == WARNING_EMERGENCY else 2)   # batteryCheck.cpp severities
        # failsafe.cpp: a warning no worse than at arming (COM_ARM_BAT_MIN let it arm) only warns
        act = int(self.params["COM_LOW_BAT_ACT"]) if warning > self._battery_warning_at_arming else 0
        if self._flying():
            self._act("battery " + text.split()[0].lower(), battery_action(act, warning), "Failsafe activated")
