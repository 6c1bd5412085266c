"""``link.offboard`` over Zenoh: px4_link's Offboard (validation, fence, velocity expiry, episodes,
the OFFBOARD loss hook) with PX4's uORB stream instead of SET_POSITION_TARGET_LOCAL_NED.

Each tick of the core's 20 Hz send thread (and each new target at once) publishes
``offboard_control_mode`` (the flag of the setpoint kind) then ``trajectory_setpoint`` (the unused
fields NaN, ``timestamp`` 0: PX4 overwrites it), as the traces' flight did; 20 Hz keeps every gap far
under COM_OF_LOSS_T (1 s). Before asking DO_SET_MODE OFFBOARD it waits for
``failsafe_flags.offboard_control_signal_lost`` to clear: PX4 ACCEPTS OFFBOARD while disarmed with no
stream, then refuses to arm (px4_zenoh_traces variants V5/V7).
"""
from __future__ import annotations

import math
import time
from typing import Any

from px4_link.commands import CommandAck, CommandTemporarilyRejected
from px4_link.offboard import PRESTREAM_S, VELOCITY_TIMEOUT_S, Offboard
from px4_link.targets import Geofence, PositionTarget, Target, TargetRefused
from px4_link.wire import mavlink2

from . import topics as tp
from .core import ZenohCore

NAN3 = [math.nan] * 3


class ZenohOffboard(Offboard):
    def __init__(self, core: ZenohCore, geofence: Geofence | None, max_speed: float | None,
                 velocity_timeout_s: float = VELOCITY_TIMEOUT_S) -> None:
        super().__init__(core, geofence, max_speed, velocity_timeout_s)
        self._zcore = core

    def uorb_messages(self, sp: Target) -> tuple[Any, Any]:
        """(offboard_control_mode, trajectory_setpoint) for what goes to PX4."""
        core = self._zcore
        position = isinstance(sp, PositionTarget)
        mode = core.message(tp.OFFBOARD_MODE, timestamp=0, position=position, velocity=not position,
                            acceleration=False, attitude=False, body_rate=False, thrust_and_torque=False,
                            direct_actuator=False)
        if isinstance(sp, PositionTarget):
            pos, vel = [sp.x, sp.y, sp.z], NAN3
        else:
            pos, vel = NAN3, [sp.vx, sp.vy, sp.vz]
        traj = core.message(tp.TRAJECTORY, timestamp=0, position=list(pos), velocity=list(vel),
                            acceleration=list(NAN3), jerk=list(NAN3),
                            yaw=math.nan if sp.yaw is None else sp.yaw, yawspeed=math.nan)
        return mode, traj

    def _send(self, sp: Target, now: float) -> None:
        core = self._zcore
        if not core.can_send:
            return
        mode, traj = self.uorb_messages(self.outgoing(sp, now))
        if core.publish(tp.OFFBOARD_MODE, mode) and core.publish(tp.TRAJECTORY, traj):
            core.count("setpoints_sent")
        else:
            core.count("setpoints_unsent")
            core.rlog.warning("nokey", "px4_zenoh: setpoint not sent: PX4 has not announced %s and %s "
                                       "(no token yet, or a hash mismatch)", tp.OFFBOARD_MODE.name, tp.TRAJECTORY.name)

    def start(self, prestream_s: float = PRESTREAM_S, confirm_timeout: float = 3.0) -> CommandAck:
        core = self._zcore
        with self._lock:
            if self.setpoint is None:
                raise TargetRefused("no_setpoint", "offboard.start needs a setpoint first (call set_setpoint)")
            if not self._streaming:
                self._streaming = True
                self._stream_started = time.monotonic()
        if not core.wait_until(lambda: core.offboard_signal_lost is False, confirm_timeout):
            raise CommandTemporarilyRejected(
                mavlink2.MAV_CMD_DO_SET_MODE, None,
                f"OFFBOARD not asked: PX4 still reports offboard_control_signal_lost after {confirm_timeout:g} s "
                "of setpoints (does PX4 subscribe to our offboard_control_mode key?)")
        return super().start(prestream_s, confirm_timeout)
