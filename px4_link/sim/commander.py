"""The parts of PX4's commander/navigator the simulator reproduces.

Behaviour copied from PX4 (src/modules/commander, checked against Commander.cpp and
failsafe/failsafe.cpp):
- Boots disarmed in AUTO.LOITER (Hold), PX4's initial user-intended mode. After disarming
  it returns to the last mode the user selected that does not prevent arming
  (UserModeIntention's nav_state_after_disarming): OFFBOARD after an offboard mission, so
  a vehicle landed from OFFBOARD sits disarmed in OFFBOARD (real SITL trace: 50.8 s).
- Mode requests follow commander/UserModeIntention.cpp: while disarmed every mode PX4 knows is
  accepted (the user intention changes; whether the mode can run is checked at arming), while
  armed a mode must be able to run (commander/ModeUtil/mode_requirements.cpp, checked as
  failsafe/framework.cpp modeCanRun does), else TEMPORARILY_REJECTED; LAND is always allowed
  ("emergency mode"), nothing leaves TERMINATION.
- OFFBOARD is available as soon as a setpoint is recent (within COM_OF_LOSS_T) and the estimate
  it needs is valid (commander/HealthAndArmingChecks/checks/offboardCheck.cpp): no warm-up. In
  OFFBOARD a gap longer than COM_OF_LOSS_T (plus PX4's detection latency, ~0.4 s) triggers the
  COM_OBL_RC_ACT failsafe when armed. PX4's default (0) is Position mode, which needs RC: without RC
  the failsafe framework falls back to Return (AUTO.RTL), status CRITICAL. COM_FAIL_ACT_T's
  hold only applies when a user could take over with RC, so never here. Disarmed, nothing
  happens (framework.cpp getSelectedAction: no action while disarmed; real PX4 stays in OFFBOARD).
- Pre-arm: the estimator needs ``estimator_warmup_s`` after boot (PX4 SITL: 4.1 s to "Ready for
  takeoff"); until then "Preflight Fail: heading estimate not stable"
  (HealthAndArmingChecks/checks/estimatorCheck.cpp) and arming is refused with
  "Arming denied: Resolve system health failures first" (Commander.cpp arm()).
- Takeoff: motors spool up for COM_SPOOLUP_TIME, then the climb-rate limit ramps over
  MPC_TKO_RAMP_T (SITL: arm -> 4 m in ~5.5-6 s). Land detection takes ~3 s of ground
  contact, then COM_DISARM_LAND.
- When AUTO.LAND starts, the navigator asks the gimbal manager to point neutral: three
  COMMAND_LONGs to component 0 of our own system, the first resent up to 3x unanswered.
- Manual modes cannot run (and a vehicle in one cannot arm): the simulator has no RC input.
- Disarming in the air needs the force magic (param2 = 21196); auto-disarm after
  COM_DISARM_PRFLT without takeoff and COM_DISARM_LAND after landing.
- Unknown commands get UNSUPPORTED; DO_FLIGHTTERMINATION while disarmed gets DENIED.
"""
from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..modes import MAIN_AUTO, decode_main_sub
from .failsafe import offboard_loss_action
from .params import ParamStore
from .physics import Limits, PointMassQuad, Target

ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
EARTH_RADIUS_M = 6378137.0   # the simulators' flat-earth projection around home (protocol.py, uorb_out.py)

CMD_NAV_RETURN_TO_LAUNCH = 20
CMD_NAV_LAND = 21
CMD_NAV_TAKEOFF = 22
CMD_DO_SET_MODE = 176
CMD_DO_REPOSITION = 192
CMD_DO_FLIGHTTERMINATION = 185
CMD_COMPONENT_ARM_DISARM = 400

# MAV_LANDED_STATE
ON_GROUND, IN_AIR, TAKING_OFF, LANDING = 1, 2, 3, 4

# Boot -> pre-arm checks pass in real PX4 SITL (SIH): EVENT "arming checks ok" at 4.13 s after boot
# and SYS_STATUS's PREARM_CHECK health bit from 4.1-4.3 s (px4_traces/px4_to_companion.tlog);
# vehicle_status.pre_flight_checks_pass at 3.81 s in the Zenoh ground trace.
PX4_ESTIMATOR_WARMUP_S = 4.1
# Boot -> GPS and the estimator's first outputs (SYS_STATUS present bits, trace: ~2.2 s after boot);
# PX4 prints its first health report's failure then.
SENSORS_UP_S = 2.2
# COM_OF_LOSS_T is checked against the offboard_control_mode timestamp, and the failsafe
# state machine reacts a few cycles later: PX4 SITL switches ~1.4 s after the last setpoint.
OFFBOARD_LOSS_LATENCY_S = 0.4
# Land detector chain (ground contact -> maybe landed -> landed) with the thrust wind-down
# of a landing multicopter; SITL traces show 2.9-3.9 s from touchdown to ON_GROUND.
LAND_DETECT_S = 3.5
# PX4's takeoff ramp starts from a negative velocity so the vehicle stays on the ground
# until thrust builds up; this is the part of the ramp spent below zero.
TAKEOFF_RAMP_DEAD_S = 1.2
MANUAL_MODES = {"MANUAL", "ALTCTL", "POSCTL", "POSCTL.ORBIT", "POSCTL.SLOW", "ACRO",
                "STABILIZED", "RATTITUDE"}
# Modes a user may select in the simulator (while disarmed any of them is accepted, as PX4 does).
KNOWN_MODES = MANUAL_MODES | {"OFFBOARD", "AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LAND", "AUTO.RTL",
                              "AUTO.MISSION"}
HOLDING_MODES = {"AUTO.LOITER", "POSCTL", "ALTCTL", "STABILIZED"}
NO_ARM_MODES = {"AUTO.LAND", "AUTO.RTL", "TERMINATION"}
# Every mode PX4's failsafe framework may put the vehicle in (incl. fallbacks).
FAILSAFE_MODES = frozenset({"POSCTL", "ALTCTL", "STABILIZED", "AUTO.RTL", "AUTO.LAND",
                            "AUTO.LOITER", "TERMINATION", "AUTO.PRECLAND"})
USER_REASONS = ("command", "takeoff complete")   # what changes PX4's user mode intention
CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
CMD_DO_GIMBAL_MANAGER_CONFIGURE = 1001
GIMBAL_RESEND_S = 0.5
GIMBAL_RESENDS = 3
GIMBAL_DELAY_S = 0.27             # LAND start -> first gimbal command in the SITL traces


def int_param(v: float, default: int = 0) -> int:
    """A COMMAND_LONG param as an integer; NaN (MAVSDK's "unused") reads as ``default``."""
    return int(round(v)) if math.isfinite(v) else default


@dataclass(frozen=True, slots=True)
class ReceivedSetpoint:
    """A SET_POSITION_TARGET_LOCAL_NED as the simulator understood it."""
    time: float
    type_mask: int
    frame: int
    position: tuple[float, float, float] | None
    velocity: tuple[float, float, float] | None
    yaw: float | None
    source_system: int


@dataclass(frozen=True, slots=True)
class ModeChange:
    time: float
    old: str
    new: str
    reason: str


@dataclass(frozen=True, slots=True)
class FailsafeEvent:
    time: float
    cause: str
    action: str


@dataclass(slots=True)
class OutgoingCommand:
    """A COMMAND_LONG PX4 itself sends (to the gimbal manager, ...)."""
    due: float
    command: int
    params: tuple[float, ...]
    target_component: int = 0
    confirmation: int = 0
    resends_left: int = 0


@dataclass(slots=True)
class CommandResult:
    result: int
    text: str | None = None   # STATUSTEXT PX4 would print alongside


@dataclass
class Commander:
    params: ParamStore
    vehicle: PointMassQuad
    now: float
    mode: str = "AUTO.LOITER"
    armed: bool = False
    landed_state: int = ON_GROUND
    failsafe: bool = False
    mode_log: list[ModeChange] = field(default_factory=list)
    setpoints_received: int = 0
    last_setpoint: ReceivedSetpoint | None = None
    statustexts: list[tuple[int, str]] = field(default_factory=list)  # (severity, text) to send
    home_alt: float = 488.0  # AMSL altitude of home, for NAV_TAKEOFF's AMSL param7
    home_latlon: tuple[float, float] = (47.397742, 8.545594)   # for DO_REPOSITION's lat/lon
    failsafe_log: list[FailsafeEvent] = field(default_factory=list)
    outgoing: list[OutgoingCommand] = field(default_factory=list)
    landed_at: float | None = None           # last auto/commanded disarm on the ground
    setpoints_since_landed: int = 0
    estimator_warmup_s: float = PX4_ESTIMATOR_WARMUP_S
    estimate_lost: bool = False    # an injected estimate loss (sim/faults.py)
    # COM_OF_LOSS_T -> failsafe latency: the MAVLink build's (OFFBOARD_LOSS_LATENCY_S) by default; PX4's
    # Zenoh build reacts in ~0.1 s (px4_zenoh_traces loss: 1.096 s), which px4_zenoh.sim passes.
    offboard_loss_latency_s: float = OFFBOARD_LOSS_LATENCY_S
    # the GCS-link arming check (sim/failsafe.py rcAndDataLinkCheck), wired by the simulator
    link_check: Callable[[], str | None] | None = None

    def __post_init__(self) -> None:
        self._lock = threading.RLock()
        self._boot = self.now
        self._health_reported = False     # the first health report (a failure) was printed
        self._ready_reported = False      # "Ready for takeoff!" was printed
        self._sp_last: float | None = None
        self._armed_at: float | None = None
        self._took_off = False
        self._landed_since: float | None = self.now
        self._hold_pos = np.zeros(3)
        self._hold_yaw: float | None = None
        self._repositioning = False       # the hold point is a DO_REPOSITION's (flown at cruise speed)
        self._takeoff_alt = 0.0
        self._rtl_phase = ""
        self._pending: tuple[float, str] | None = None   # delayed failsafe action (at, mode)
        self._mode_after_disarm = self.mode
        # PX4's nav_state_user_intention (CURRENT_MODE's intended_custom_mode): what the user last chose,
        # which a failsafe's mode does not change.
        self.user_mode = self.mode
        self._ramp_from: float | None = None     # arming time while the takeoff ramp runs

    # ------------------------------------------------------------ helpers
    def _say(self, text: str, severity: int = 4) -> None:
        self.statustexts.append((severity, text))

    def _set_mode(self, new: str, reason: str) -> None:
        if new == self.mode:
            return
        self.mode_log.append(ModeChange(self.now, self.mode, new, reason))
        self.mode = new
        self._pending = None  # any mode change supersedes a delayed failsafe action
        if reason in USER_REASONS and new not in NO_ARM_MODES:
            self._mode_after_disarm = new
        if reason in USER_REASONS or reason.startswith("disarmed"):   # UserModeIntention: change, onDisarm
            self.user_mode = new
        self._enter(new)

    def _enter(self, mode: str) -> None:
        v = self.vehicle
        self._repositioning = False
        if mode in HOLDING_MODES:
            self._hold_pos = v.pos.copy()
            self._hold_yaw = v.yaw
        elif mode == "AUTO.TAKEOFF":
            self._hold_pos = np.array([v.pos[0], v.pos[1], -self._takeoff_alt])
            self._hold_yaw = v.yaw
        elif mode == "AUTO.RTL":
            self._rtl_phase = "climb"
        elif mode == "AUTO.LAND" and self.armed:
            self._queue_gimbal_neutral()

    def _queue_gimbal_neutral(self) -> None:
        # What navigator's land does through the gimbal manager (trace: 36.45 s, 59.50 s):
        # take control as primary, point neutral, release; only the first is resent.
        at = self.now + GIMBAL_DELAY_S
        sysid = int(self.params["MAV_SYS_ID"])
        nan = math.nan
        self.outgoing += [
            OutgoingCommand(at, CMD_DO_GIMBAL_MANAGER_CONFIGURE, (sysid, 1, -1, -1, 0, 0, 0),
                            resends_left=GIMBAL_RESENDS),
            OutgoingCommand(at, CMD_DO_GIMBAL_MANAGER_PITCHYAW, (nan, nan, nan, nan, 2, 0, 0)),
            OutgoingCommand(at, CMD_DO_GIMBAL_MANAGER_CONFIGURE, (-3, -3, -1, -1, 0, 0, 0)),
        ]

    def take_outgoing(self) -> list[OutgoingCommand]:
        """Commands due now; resendable ones stay queued until acked or out of resends."""
        with self._lock:
            due = [c for c in self.outgoing if c.due <= self.now]
            out = [OutgoingCommand(c.due, c.command, c.params, c.target_component, c.confirmation)
                   for c in due]
            for c in due:
                if c.resends_left > 0:
                    c.resends_left -= 1
                    c.confirmation += 1
                    c.due = self.now + GIMBAL_RESEND_S
                else:
                    self.outgoing.remove(c)
            return out

    def on_command_ack(self, command: int) -> None:
        with self._lock:
            self.outgoing = [c for c in self.outgoing if c.command != command or c.confirmation == 0]
    # ------------------------------------------------------------ health
    def since_boot(self) -> float:
        return self.now - self._boot

    def sensors_up(self) -> bool:
        """GPS and the estimator's first outputs are there (SYS_STATUS present bits)."""
        return self.since_boot() >= min(SENSORS_UP_S, self.estimator_warmup_s)

    def estimate_valid(self) -> bool:
        """Local/global position, velocity and heading usable (EKF2 aligned, heading stable)."""
        return self.since_boot() >= self.estimator_warmup_s and not self.estimate_lost

    def preflight_failure(self) -> str | None:
        """What PX4's health and arming checks report now, disarmed (None: all pass)."""
        if not self.estimate_valid():
            # HealthAndArmingChecks/checks/estimatorCheck.cpp checkEstimatorStatus
            return "Preflight Fail: heading estimate not stable"
        return None

    def _report_health(self) -> None:
        # Commander prints the first failing report and, once everything passes,
        # "Ready for takeoff!" (Commander.cpp, health report changes; the SITL console shows both).
        if not self._health_reported and self.sensors_up():
            self._health_reported = True
            failure = self.preflight_failure()
            if failure is not None:
                self._say(failure, 2)
        if not self._ready_reported and self.preflight_failure() is None:
            self._ready_reported = True
            self._health_reported = True
            self._say("Ready for takeoff!", 6)

    def offboard_signal_ok(self) -> bool:
        """commander/HealthAndArmingChecks/checks/offboardCheck.cpp: a setpoint within COM_OF_LOSS_T,
        and the estimate a position / velocity setpoint needs is valid. No warm-up."""
        if self._sp_last is None:
            return False
        recent = self.now < self._sp_last + float(self.params["COM_OF_LOSS_T"])
        return recent and self.estimate_valid()

    def _can_run(self, mode: str) -> str | None:
        """None if ``mode`` can run now, else why: commander/ModeUtil/mode_requirements.cpp's
        requirements, checked as failsafe/framework.cpp modeCanRun does."""
        if mode == "OFFBOARD":   # mode_req_offboard_signal (+ attitude)
            return None if self.offboard_signal_ok() else "No offboard signal"
        if mode in MANUAL_MODES:   # mode_req_manual_control: the simulator has no RC
            return "No manual control input"
        if mode in ("AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.RTL"):
            # LOITER/RTL: mode_req_global_position + local_position; TAKEOFF (rotary wing):
            # mode_req_local_position + local_alt; RTL also mode_req_home_position, which the
            # simulator has whenever its estimate is valid (home = the boot position).
            return None if self.estimate_valid() else "No valid position estimate"
        if mode == "AUTO.LAND":   # mode_req_local_position_relaxed + local_alt
            return None if self.estimate_valid() else "No valid position estimate"
        if mode == "AUTO.MISSION":   # mode_req_mission
            return "No valid mission available"
        return f"{mode} not supported by the simulator"

    # ------------------------------------------------------------ inputs
    def on_setpoint(self, sp: ReceivedSetpoint) -> None:
        with self._lock:
            self.setpoints_received += 1
            if self.landed_at is not None and not self.armed:
                self.setpoints_since_landed += 1
            self.last_setpoint = sp
            self._sp_last = sp.time

    def can_arm_refusal(self) -> str | None:
        """Why PX4's canArm(nav_state) fails now (None: it passes): every health and arming check, plus the
        current mode's requirements and mode_req_prevent_arming (HealthAndArmingChecks, mode_requirements.cpp).
        Commander.cpp evaluates it at 10 Hz into vehicle_status.pre_flight_checks_pass, the verdict a client
        waits on before it arms."""
        if self.preflight_failure() is not None:
            return "Arming denied: Resolve system health failures first"
        if self.link_check is not None and (why := self.link_check()) is not None:
            return why
        return self._mode_arming_refusal()

    def _mode_arming_refusal(self) -> str | None:
        if self.mode in NO_ARM_MODES:
            return f"Arming denied: not possible in {self.mode}"
        if self.mode == "OFFBOARD" and not self.offboard_signal_ok():
            return "Arming denied: no offboard signal"
        why = self._can_run(self.mode)
        return None if why is None else f"Arming denied: {why}"

    def arming_refusal(self) -> str | None:
        """Why an ARM command would be refused now (None: it is accepted), disarmed: canArm, on the ground."""
        refusal = self.can_arm_refusal()
        if refusal is None and self.landed_state != ON_GROUND:
            return "Arming denied: not landed"
        return refusal

    def armable(self) -> bool:
        """What PX4's pre-arm checks would say now (SYS_STATUS PREARM_CHECK health)."""
        with self._lock:
            return self.armed or self.arming_refusal() is None

    def handle_command(self, command: int, p: list[float], now: float | None = None) -> CommandResult:
        with self._lock:
            if now is not None:
                self.now = now
            if command == CMD_COMPONENT_ARM_DISARM:
                return self._arm_disarm(p)
            if command == CMD_DO_SET_MODE:
                return self._do_set_mode(p)
            if command == CMD_NAV_TAKEOFF:
                r = self._request_mode("AUTO.TAKEOFF", "command")   # Commander.cpp NAV_TAKEOFF
                if r.result == ACCEPTED:
                    self._set_takeoff_altitude(p[6])
                return r
            if command == CMD_DO_REPOSITION:
                return self._reposition(p)
            if command == CMD_NAV_LAND:
                # Commander.cpp NAV_LAND: forced, always available ("emergency mode"); only
                # TERMINATION is never left (UserModeIntention.cpp).
                if self.mode == "TERMINATION":
                    return CommandResult(TEMPORARILY_REJECTED)
                self._set_mode("AUTO.LAND", "command")
                return CommandResult(ACCEPTED, "Landing at current position")
            if command == CMD_NAV_RETURN_TO_LAUNCH:
                r = self._request_mode("AUTO.RTL", "command")   # Commander.cpp NAV_RETURN_TO_LAUNCH
                if r.result == ACCEPTED:
                    r.text = "Returning to launch"
                return r
            if command == CMD_DO_FLIGHTTERMINATION:
                if p[0] > 0.5 and self.armed:
                    self._set_mode("TERMINATION", "command")
                    self._disarm("termination")
                    return CommandResult(ACCEPTED)
                return CommandResult(DENIED)
            return CommandResult(UNSUPPORTED)

    def _set_takeoff_altitude(self, amsl: float) -> None:
        """navigator/takeoff.cpp set_takeoff_position: param7 (AMSL) or, when NaN, the current
        altitude + MIS_TAKEOFF_ALT; never lower than now ("Already higher than takeoff
        altitude"), so a NAV_TAKEOFF in flight climbs or holds, never restarts from the ground."""
        current = -float(self.vehicle.pos[2])
        if math.isfinite(amsl):
            alt = max(amsl - self.home_alt, 1.0)
        else:
            alt = current + float(self.params["MIS_TAKEOFF_ALT"])
            self._say(f"Using default takeoff altitude: {float(self.params['MIS_TAKEOFF_ALT']):.1f} m", 6)
        if alt < current:
            self._say("Already higher than takeoff altitude", 2)
            alt = current
        self._takeoff_alt = alt
        self._enter("AUTO.TAKEOFF")

    def _reposition(self, p: list[float]) -> CommandResult:
        """Commander.cpp DO_REPOSITION: param2 must be exactly MAV_DO_REPOSITION_FLAGS_CHANGE_MODE (1),
        anything else is UNSUPPORTED; then Hold is asked as for a mode switch. navigator_main.cpp flies to
        param5/6 (lat/lon, else here) at param7 (AMSL, else the current altitude) only when armed, and
        not at all when the point is outside the geofence ("Reposition is outside geofence")."""
        flags = int_param(p[1])
        if flags != 1:
            return CommandResult(UNSUPPORTED)
        r = self._request_mode("AUTO.LOITER", "command")
        if r.result != ACCEPTED or not self.armed:
            return r
        v = self.vehicle
        north, east = float(v.pos[0]), float(v.pos[1])
        if math.isfinite(p[4]) and math.isfinite(p[5]):
            lat0, lon0 = self.home_latlon
            north = math.radians(p[4] - lat0) * EARTH_RADIUS_M
            east = math.radians(p[5] - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        down = -(p[6] - self.home_alt) if math.isfinite(p[6]) else float(v.pos[2])
        # geofence.cpp checkPointAgainstAllGeofences: the max distance and altitude from home (> 0 = on)
        hor, ver = float(self.params["GF_MAX_HOR_DIST"]), float(self.params["GF_MAX_VER_DIST"])
        fenced = int(self.params["GF_ACTION"]) not in (0, 1)     # NONE and WARN do not refuse
        if fenced and ((hor > 0 and math.hypot(north, east) > hor) or (ver > 0 and -down > ver)):
            self._say("Reposition is outside geofence", 2)
            return r
        self._hold_pos = np.array([north, east, down])
        self._repositioning = True
        if math.isfinite(p[3]):
            self._hold_yaw = p[3]
        return r

    def _request_mode(self, mode: str, reason: str) -> CommandResult:
        """commander/UserModeIntention.cpp change(): always allowed while disarmed, else the mode
        must be able to run; never out of TERMINATION."""
        if self.mode == "TERMINATION":
            return CommandResult(TEMPORARILY_REJECTED, f"{mode} rejected: in TERMINATION")
        if mode not in KNOWN_MODES:   # the simulator cannot fly it: refused in any state
            why: str | None = f"{mode} not supported by the simulator"
        else:
            why = self._can_run(mode) if self.armed else None
        if why is not None:
            # PX4 prints "Switching to <mode> is currently not available"; STATUSTEXT holds
            # 50 characters, so keep the reason instead.
            return CommandResult(TEMPORARILY_REJECTED, f"{mode} rejected: {why}")
        self._set_mode(mode, reason)
        return CommandResult(ACCEPTED)

    def _do_set_mode(self, p: list[float]) -> CommandResult:
        base_mode, main, sub = int_param(p[0]), int_param(p[1]), int_param(p[2])
        # Commander.cpp DO_SET_MODE: the mode asked, then UserModeIntention::change; anything it
        # cannot map is TRANSITION_DENIED, i.e. TEMPORARILY_REJECTED.
        if not base_mode & 1:   # not MAV_MODE_FLAG_CUSTOM_MODE_ENABLED: standard flags
            if base_mode & 4:   # AUTO_ENABLED -> mission
                return self._request_mode("AUTO.MISSION", "command")
            if base_mode & 64:  # MANUAL_INPUT_ENABLED -> a stick mode
                stick = "POSCTL" if base_mode & 8 else "STABILIZED" if base_mode & 16 else "MANUAL"
                return self._request_mode(stick, "command")
            return CommandResult(TEMPORARILY_REJECTED, "Unsupported base mode")
        name = decode_main_sub(main, sub if main == MAIN_AUTO or main == 3 else 0)
        if name.startswith("UNKNOWN"):
            return CommandResult(TEMPORARILY_REJECTED, f"Unsupported mode {main}.{sub}")
        if name == "AUTO.LAND" and self.mode != "TERMINATION":   # forced, as NAV_LAND
            self._set_mode(name, "command")
            return CommandResult(ACCEPTED)
        return self._request_mode(name, "command")

    def _arm_disarm(self, p: list[float]) -> CommandResult:
        action = int_param(p[0], -1)
        forced = int_param(p[1]) == 21196
        if action == 1:
            if self.armed:
                return CommandResult(ACCEPTED)
            if not forced:   # Commander.cpp arm(): canArm(nav_state), else TRANSITION_DENIED
                refusal = self.arming_refusal()
                if refusal is not None:
                    failure = self.preflight_failure()
                    if failure is not None:   # the report's failures are printed first
                        self._say(failure, 2)
                    return CommandResult(TEMPORARILY_REJECTED, refusal)
            self.armed = True
            self._armed_at = self.now
            self._took_off = False
            self._ramp_from = self.now if self.landed_state == ON_GROUND else None
            self.landed_at = None
            self.setpoints_since_landed = 0
            if self.mode in HOLDING_MODES:
                self._enter(self.mode)
            return CommandResult(ACCEPTED, "Armed by external command")
        if action == 0:
            if not self.armed:
                return CommandResult(ACCEPTED)
            if self.landed_state != ON_GROUND and not forced:
                return CommandResult(TEMPORARILY_REJECTED, "Disarming denied: not landed")
            self._disarm("command")
            return CommandResult(ACCEPTED, "Disarmed by external command")
        return CommandResult(UNSUPPORTED, f"Unsupported ARM_DISARM param: {p[0]}")

    def _disarm(self, reason: str) -> None:
        self.armed = False
        self._armed_at = None
        self.failsafe = False
        self.outgoing = [c for c in self.outgoing if c.resends_left == 0]
        if self.landed_state == ON_GROUND:
            self.landed_at = self.now
            self.setpoints_since_landed = 0
        if reason == "termination":
            return
        after = self._mode_after_disarm
        if after == "AUTO.TAKEOFF":   # a finished or aborted takeoff leaves nothing to resume
            after = "AUTO.LOITER"
        if self.mode != after:
            self._set_mode(after, f"disarmed ({reason})")

    # ------------------------------------------------------------ periodic
    def update(self, now: float) -> Target | None:
        """Run the state machine at time ``now``; return what the airframe should do."""
        with self._lock:
            self.now = now
            self._report_health()
            self._update_landed()
            self._check_offboard_loss()
            if self._pending is not None and now >= self._pending[0]:
                mode = self._pending[1]
                self._pending = None
                self._set_mode(mode, "failsafe: delayed action")
            self._auto_disarm()
            return self._target() if self.armed else None

    def _update_landed(self) -> None:
        v = self.vehicle
        if v.on_ground and abs(v.vel[2]) < 0.1:
            if self._landed_since is None:
                self._landed_since = self.now
            detect = LAND_DETECT_S if self._took_off else 0.3
            if self.now - self._landed_since >= detect or not self.armed:
                if self.landed_state != ON_GROUND:
                    self._landed_since = self.now   # COM_DISARM_LAND counts from detection
                self.landed_state = ON_GROUND
        else:
            self._landed_since = None
            if -v.pos[2] > 0.1:
                if self.armed and self.landed_state == ON_GROUND:
                    self._took_off = True
                if self.mode == "AUTO.TAKEOFF":
                    self.landed_state = TAKING_OFF
                elif self.mode == "AUTO.LAND" or (self.mode == "AUTO.RTL" and self._rtl_phase == "land"):
                    self.landed_state = LANDING
                else:
                    self.landed_state = IN_AIR

    def _check_offboard_loss(self) -> None:
        if self.mode != "OFFBOARD":
            return
        silent = math.inf if self._sp_last is None else self.now - self._sp_last
        if silent <= float(self.params["COM_OF_LOSS_T"]) + self.offboard_loss_latency_s:
            return
        if not self.armed:
            # failsafe/framework.cpp getSelectedAction: no action while disarmed; PX4 stays in
            # OFFBOARD (Zenoh variants trace V5b/V7: nav_state 14, arming then refused).
            return
        # COM_OBL_RC_ACT; its stick modes fall back to NAV_RCL_ACT without RC (sim/failsafe.py)
        action = offboard_loss_action(self.params)
        self.failsafe_action("offboard loss", action, f"Failsafe: no offboard signal, action {action}")

    # ------------------------------------------------------------ hooks of sim/failsafe.py and sim/faults.py
    def say(self, text: str, severity: int = 4) -> None:
        self._say(text, severity)

    def failsafe_action(self, cause: str, mode: str, text: str, delay_s: float = 0.0) -> None:
        """Enter a failsafe: ``mode`` (or "TERMINATION" / "DISARM"), after ``delay_s`` of Hold
        (COM_FAIL_ACT_T, failsafe/framework.cpp) when > 0."""
        with self._lock:
            self._say(text, severity=2)
            self.failsafe = True
            self.failsafe_log.append(FailsafeEvent(self.now, cause, mode))
            if mode == "TERMINATION":
                self._set_mode("TERMINATION", f"failsafe: {cause}")
                self._disarm("termination")
            elif mode == "DISARM":
                self._set_mode("AUTO.LOITER", f"failsafe: {cause}")
                self._disarm("failsafe")
            elif delay_s > 0:
                self._set_mode("AUTO.LOITER", f"failsafe: {cause}, hold first")
                self._pending = (self.now + delay_s, mode)
            else:
                self._set_mode(mode, f"failsafe: {cause}")

    def restore_mode(self, mode: str, reason: str) -> None:
        """A mode fallback cleared: back to the user's mode (failsafe/framework.cpp)."""
        with self._lock:
            self.failsafe = False
            self._set_mode(mode, reason)

    def on_position_reset(self, delta: np.ndarray) -> None:
        """An EKF reset moved the local frame by ``delta``: PX4's flight tasks shift their hold
        setpoints with it (flight_mode_manager FlightTask::_checkEkfResetCounters), so a holding
        vehicle stays where it is; an OFFBOARD setpoint is the companion's and is not shifted."""
        with self._lock:
            self._hold_pos = self._hold_pos + np.asarray(delta, dtype=float)

    def _auto_disarm(self) -> None:
        if not self.armed or self.landed_state != ON_GROUND or self._landed_since is None:
            return
        if not self._took_off:
            t = float(self.params["COM_DISARM_PRFLT"])
            if t > 0 and self._armed_at is not None and self.now - self._armed_at > t \
                    and self.mode != "AUTO.TAKEOFF":
                self._say("Disarmed: no takeoff within COM_DISARM_PRFLT", 6)
                self._disarm("auto preflight")
        else:
            t = float(self.params["COM_DISARM_LAND"])
            if t > 0 and self.now - self._landed_since > t:
                self._say("Disarmed: landed", 6)
                self._disarm("auto landed")

    def _target(self) -> Target | None:
        t = self._mode_target()
        if t is None or self._ramp_from is None:
            return t
        ramp = self._climb_limit(self.now - self._ramp_from)
        if ramp >= float(self.params["MPC_Z_VEL_MAX_UP"]):
            self._ramp_from = None
        t.max_up = ramp if t.max_up is None else min(t.max_up, ramp)
        return t

    def _climb_limit(self, since_arming: float) -> float:
        """PX4's spool-up then takeoff ramp, as a climb-rate limit (m/s)."""
        up = float(self.params["MPC_Z_VEL_MAX_UP"])
        ramp_t = float(self.params["MPC_TKO_RAMP_T"])
        t = since_arming - float(self.params["COM_SPOOLUP_TIME"]) - TAKEOFF_RAMP_DEAD_S
        if t <= 0:
            return 0.0
        return up if ramp_t <= 0 else min(up, up * t / ramp_t)

    def _mode_target(self) -> Target | None:
        v = self.vehicle
        mode = self.mode
        if mode in HOLDING_MODES:
            if self.landed_state == ON_GROUND:
                return Target(position=np.array([v.pos[0], v.pos[1], 0.0]), yaw=self._hold_yaw)
            # Loiter flies to a reposition point at MPC_XY_CRUISE (navigator: cruising_speed -1 = default)
            cruise = float(self.params["MPC_XY_CRUISE"]) if self._repositioning else None
            return Target(position=self._hold_pos, yaw=self._hold_yaw, max_xy=cruise)
        if mode == "AUTO.TAKEOFF":
            tko = float(self.params["MPC_TKO_SPEED"])
            if abs(v.pos[2] - self._hold_pos[2]) < max(0.1 * self._takeoff_alt, 0.2):
                self._set_mode("AUTO.LOITER", "takeoff complete")
                self._hold_pos = np.array([self._hold_pos[0], self._hold_pos[1], -self._takeoff_alt])
                return Target(position=self._hold_pos, yaw=self._hold_yaw)
            return Target(position=self._hold_pos, yaw=self._hold_yaw, max_up=tko)
        if mode == "AUTO.LAND":
            return Target(position=np.array([v.pos[0], v.pos[1], 0.0]),
                          velocity=np.array([0.0, 0.0, float(self.params["MPC_LAND_SPEED"])]),
                          max_dn=float(self.params["MPC_LAND_SPEED"]))
        if mode == "AUTO.RTL":
            return self._rtl_target()
        if mode == "OFFBOARD":
            sp = self.last_setpoint
            if sp is None:
                return Target(position=v.pos.copy())
            pos = np.array(sp.position) if sp.position is not None else None
            vel = np.array(sp.velocity) if sp.velocity is not None else None
            if pos is None and vel is None:
                pos = v.pos.copy()
            return Target(position=pos, velocity=vel, yaw=sp.yaw)
        return None  # TERMINATION or unknown: motors off

    def _rtl_target(self) -> Target:
        v = self.vehicle
        ret_alt = max(float(self.params["RTL_RETURN_ALT"]), -v.pos[2])
        cruise = float(self.params["MPC_XY_CRUISE"])
        if self.landed_state == ON_GROUND and self._rtl_phase != "land":
            return Target(position=np.array([v.pos[0], v.pos[1], 0.0]))
        if self._rtl_phase == "climb":
            if -v.pos[2] >= ret_alt - 0.3 or math.hypot(v.pos[0], v.pos[1]) < 0.5:
                self._rtl_phase = "return"
            return Target(position=np.array([v.pos[0], v.pos[1], -ret_alt]))
        if self._rtl_phase == "return":
            if math.hypot(v.pos[0], v.pos[1]) < 0.3:
                self._rtl_phase = "land"
            return Target(position=np.array([0.0, 0.0, v.pos[2]]), max_xy=cruise)
        land = float(self.params["MPC_LAND_SPEED"])
        return Target(position=np.array([0.0, 0.0, 0.0]), velocity=np.array([0.0, 0.0, land]),
                      max_dn=land)

    def limits(self) -> Limits:
        p = self.params
        return Limits(xy_vel=float(p["MPC_XY_VEL_MAX"]), z_vel_up=float(p["MPC_Z_VEL_MAX_UP"]),
                      z_vel_dn=float(p["MPC_Z_VEL_MAX_DN"]), acc_xy=float(p["MPC_ACC_HOR"]),
                      acc_up=float(p["MPC_ACC_UP_MAX"]), acc_dn=float(p["MPC_ACC_DOWN_MAX"]),
                      yaw_rate=math.radians(float(p["MPC_YAWRAUTO_MAX"])))
