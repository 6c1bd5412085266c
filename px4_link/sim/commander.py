"""The parts of PX4's commander/navigator the simulator reproduces.

Behaviour copied from PX4 (src/modules/commander, checked against Commander.cpp and
failsafe/failsafe.cpp):
- Boots disarmed in AUTO.LOITER (Hold), PX4's initial user-intended mode.
- Mode changes and arming that PX4 would refuse are answered TEMPORARILY_REJECTED
  (PX4 maps every TRANSITION_DENIED of DO_SET_MODE, NAV_TAKEOFF, NAV_RTL and
  COMPONENT_ARM_DISARM to that result); LAND is always allowed ("emergency mode").
- OFFBOARD can only be entered after ~1 s of setpoints at > 2 Hz, and in OFFBOARD a gap
  longer than COM_OF_LOSS_T triggers the COM_OBL_RC_ACT failsafe. PX4's default (0) is
  Position mode: with no RC sticks the vehicle holds where it is, in POSCTL. 3 (Return)
  and 4 (Land) first hold for COM_FAIL_ACT_T, as PX4's failsafe delay does.
- Manual modes are refused: the simulator has no RC / joystick input.
- Disarming in the air needs the force magic (param2 = 21196); auto-disarm after
  COM_DISARM_PRFLT without takeoff and COM_DISARM_LAND after landing.
- Unknown commands get UNSUPPORTED; DO_FLIGHTTERMINATION while disarmed gets DENIED.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np

from ..modes import MAIN_AUTO, decode_main_sub
from .params import ParamStore
from .physics import Limits, PointMassQuad, Target

ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4

CMD_NAV_RETURN_TO_LAUNCH = 20
CMD_NAV_LAND = 21
CMD_NAV_TAKEOFF = 22
CMD_DO_SET_MODE = 176
CMD_DO_FLIGHTTERMINATION = 185
CMD_COMPONENT_ARM_DISARM = 400

# MAV_LANDED_STATE
ON_GROUND, IN_AIR, TAKING_OFF, LANDING = 1, 2, 3, 4

OFFBOARD_MIN_RATE_GAP_S = 0.5     # "> 2 Hz": a gap above 0.5 s restarts the proof of life
OFFBOARD_WARMUP_S = 1.0           # PX4 docs: the signal must be present for > 1 s
MANUAL_MODES = {"MANUAL", "ALTCTL", "POSCTL", "POSCTL.ORBIT", "POSCTL.SLOW", "ACRO",
                "STABILIZED", "RATTITUDE"}
HOLDING_MODES = {"AUTO.LOITER", "POSCTL", "ALTCTL", "STABILIZED"}
NO_ARM_MODES = {"AUTO.LAND", "AUTO.RTL", "TERMINATION"}
OBL_ACTIONS = {0: "POSCTL", 1: "ALTCTL", 2: "STABILIZED", 3: "AUTO.RTL", 4: "AUTO.LAND",
               5: "AUTO.LOITER", 6: "TERMINATION", 7: "DISARM"}


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

    def __post_init__(self) -> None:
        self._lock = threading.RLock()
        self._sp_last: float | None = None
        self._sp_stream_start: float | None = None
        self._armed_at: float | None = None
        self._took_off = False
        self._landed_since: float | None = self.now
        self._hold_pos = np.zeros(3)
        self._hold_yaw: float | None = None
        self._takeoff_alt = 0.0
        self._rtl_phase = ""
        self._pending: tuple[float, str] | None = None   # delayed failsafe action (at, mode)

    # ------------------------------------------------------------ helpers
    def _say(self, text: str, severity: int = 4) -> None:
        self.statustexts.append((severity, text))

    def _set_mode(self, new: str, reason: str) -> None:
        if new == self.mode:
            return
        self.mode_log.append(ModeChange(self.now, self.mode, new, reason))
        self.mode = new
        self._pending = None  # any mode change supersedes a delayed failsafe action
        self._enter(new)

    def _enter(self, mode: str) -> None:
        v = self.vehicle
        if mode in HOLDING_MODES:
            self._hold_pos = v.pos.copy()
            self._hold_yaw = v.yaw
        elif mode == "AUTO.TAKEOFF":
            self._hold_pos = np.array([v.pos[0], v.pos[1], -self._takeoff_alt])
            self._hold_yaw = v.yaw
        elif mode == "AUTO.RTL":
            self._rtl_phase = "climb"

    def offboard_signal_ok(self) -> bool:
        """PX4's offboard availability: a fresh setpoint, streamed for > 1 s."""
        if self._sp_last is None or self._sp_stream_start is None:
            return False
        fresh = self.now - self._sp_last <= min(OFFBOARD_MIN_RATE_GAP_S,
                                                float(self.params["COM_OF_LOSS_T"]))
        return fresh and self.now - self._sp_stream_start >= OFFBOARD_WARMUP_S

    def _can_run(self, mode: str) -> str | None:
        """None if PX4 would allow switching to ``mode`` now, else the reason."""
        if mode == "OFFBOARD":
            return None if self.offboard_signal_ok() else "No offboard signal"
        if mode in MANUAL_MODES:
            return "No manual control input"
        if mode in ("AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LAND", "AUTO.RTL"):
            return None
        if mode == "AUTO.MISSION":
            return "No valid mission available"
        return f"{mode} not supported by the simulator"

    # ------------------------------------------------------------ inputs
    def on_setpoint(self, sp: ReceivedSetpoint) -> None:
        with self._lock:
            self.setpoints_received += 1
            self.last_setpoint = sp
            if self._sp_last is None or sp.time - self._sp_last > OFFBOARD_MIN_RATE_GAP_S:
                self._sp_stream_start = sp.time
            self._sp_last = sp.time

    def handle_command(self, command: int, p: list[float], now: float | None = None) -> CommandResult:
        with self._lock:
            if now is not None:
                self.now = now
            if command == CMD_COMPONENT_ARM_DISARM:
                return self._arm_disarm(p)
            if command == CMD_DO_SET_MODE:
                return self._do_set_mode(p)
            if command == CMD_NAV_TAKEOFF:
                alt = float(self.params["MIS_TAKEOFF_ALT"])
                if math.isfinite(p[6]):
                    alt = max(p[6] - self.home_alt, 1.0)
                self._takeoff_alt = alt
                if self.mode == "AUTO.TAKEOFF":
                    self._enter("AUTO.TAKEOFF")
                return self._request_mode("AUTO.TAKEOFF", "command")
            if command == CMD_NAV_LAND:
                self._set_mode("AUTO.LAND", "command")   # PX4 forces LAND: always available
                return CommandResult(ACCEPTED, "Landing at current position")
            if command == CMD_NAV_RETURN_TO_LAUNCH:
                return self._request_mode("AUTO.RTL", "command")
            if command == CMD_DO_FLIGHTTERMINATION:
                if p[0] > 0.5 and self.armed:
                    self._set_mode("TERMINATION", "command")
                    self._disarm("termination")
                    return CommandResult(ACCEPTED)
                return CommandResult(DENIED)
            return CommandResult(UNSUPPORTED)

    def _request_mode(self, mode: str, reason: str) -> CommandResult:
        why = self._can_run(mode)
        if why is not None:
            # PX4 prints "Switching to <mode> is currently not available"; STATUSTEXT holds
            # 50 characters, so keep the reason instead.
            return CommandResult(TEMPORARILY_REJECTED, f"{mode} rejected: {why}")
        self._set_mode(mode, reason)
        return CommandResult(ACCEPTED)

    def _do_set_mode(self, p: list[float]) -> CommandResult:
        base_mode, main, sub = int(p[0]), int(round(p[1])), int(round(p[2]))
        if not base_mode & 1:   # not MAV_MODE_FLAG_CUSTOM_MODE_ENABLED: standard flags
            if base_mode & 64:  # MANUAL_INPUT_ENABLED -> a stick mode
                return CommandResult(TEMPORARILY_REJECTED, "No manual control input")
            if base_mode & 4:   # AUTO_ENABLED -> mission
                return self._request_mode("AUTO.MISSION", "command")
            return CommandResult(ACCEPTED)  # PX4: nothing to change
        name = decode_main_sub(main, sub if main == MAIN_AUTO or main == 3 else 0)
        if name.startswith("UNKNOWN"):
            # PX4 would ACK this without changing anything; refusing is more useful.
            return CommandResult(DENIED, f"Unknown mode {main}.{sub}")
        if name == "AUTO.LAND":
            self._set_mode(name, "command")
            return CommandResult(ACCEPTED)
        return self._request_mode(name, "command")

    def _arm_disarm(self, p: list[float]) -> CommandResult:
        action = int(round(p[0]))
        forced = int(round(p[1])) == 21196
        if action == 1:
            if self.armed:
                return CommandResult(ACCEPTED)
            if not forced:
                if self.landed_state != ON_GROUND:
                    return CommandResult(TEMPORARILY_REJECTED, "Arming denied: not landed")
                if self.mode in NO_ARM_MODES:
                    return CommandResult(TEMPORARILY_REJECTED,
                                         f"Arming denied: not possible in {self.mode}")
                if self.mode == "OFFBOARD" and not self.offboard_signal_ok():
                    return CommandResult(TEMPORARILY_REJECTED, "Arming denied: no offboard signal")
            self.armed = True
            self._armed_at = self.now
            self._took_off = False
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
        if self.mode in ("AUTO.LAND", "AUTO.RTL", "AUTO.TAKEOFF") and reason != "termination":
            self._set_mode("AUTO.LOITER", f"disarmed ({reason})")

    # ------------------------------------------------------------ periodic
    def update(self, now: float) -> Target | None:
        """Run the state machine at time ``now``; return what the airframe should do."""
        with self._lock:
            self.now = now
            self._update_landed()
            self._check_offboard_loss()
            if self._pending is not None and now >= self._pending[0]:
                mode = self._pending[1]
                self._pending = None
                self._set_mode(mode, "failsafe")
            self._auto_disarm()
            return self._target() if self.armed else None

    def _update_landed(self) -> None:
        v = self.vehicle
        if v.on_ground and abs(v.vel[2]) < 0.1:
            if self._landed_since is None:
                self._landed_since = self.now
            # PX4's land detector needs a moment of ground contact.
            if self.now - self._landed_since >= 0.3 or not self.armed:
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
        if silent <= float(self.params["COM_OF_LOSS_T"]):
            return
        action = OBL_ACTIONS.get(int(self.params["COM_OBL_RC_ACT"]), "POSCTL")
        self._say(f"Failsafe activated: no offboard signal for {silent:.1f} s, "
                  f"action {action}", severity=2)
        self.failsafe = self.armed
        if action == "DISARM" or action == "TERMINATION":
            if action == "TERMINATION":
                self._set_mode("TERMINATION", "offboard loss")
            else:
                self._set_mode("AUTO.LOITER", "offboard loss")
            if self.armed:
                self._disarm("offboard loss")
            return
        delay = float(self.params["COM_FAIL_ACT_T"])
        if action in ("AUTO.RTL", "AUTO.LAND") and delay > 0 and self.armed:
            self._set_mode("AUTO.LOITER", "offboard loss")
            self._pending = (self.now + delay, action)
        else:
            self._set_mode(action, "offboard loss")

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
        v = self.vehicle
        mode = self.mode
        if mode in HOLDING_MODES:
            if self.landed_state == ON_GROUND:
                return Target(position=np.array([v.pos[0], v.pos[1], 0.0]), yaw=self._hold_yaw)
            return Target(position=self._hold_pos, yaw=self._hold_yaw)
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
