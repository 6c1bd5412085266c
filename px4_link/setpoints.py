"""Offboard setpoints and the checks they pass before anything reaches PX4.

PX4 flies whatever SET_POSITION_TARGET_LOCAL_NED says; a NaN, a typo of 1000 m or a
setpoint far outside the test area is a crash. So every setpoint is validated here, and a
rejected one raises ``SetpointRejected`` and is never sent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

# MAV_FRAME_LOCAL_NED: the only frame this link streams in.
MAV_FRAME_LOCAL_NED = 1

# POSITION_TARGET_TYPEMASK bits: a set bit means "ignore this field".
IGNORE_PX, IGNORE_PY, IGNORE_PZ = 0x1, 0x2, 0x4
IGNORE_VX, IGNORE_VY, IGNORE_VZ = 0x8, 0x10, 0x20
IGNORE_AFX, IGNORE_AFY, IGNORE_AFZ = 0x40, 0x80, 0x100
FORCE_SET = 0x200
IGNORE_YAW = 0x400
IGNORE_YAW_RATE = 0x800

IGNORE_POSITION = IGNORE_PX | IGNORE_PY | IGNORE_PZ
IGNORE_VELOCITY = IGNORE_VX | IGNORE_VY | IGNORE_VZ
IGNORE_ACCEL = IGNORE_AFX | IGNORE_AFY | IGNORE_AFZ

# The masks PX4's offboard docs use: position + yaw, velocity + yaw.
TYPE_MASK_POSITION_YAW = IGNORE_VELOCITY | IGNORE_ACCEL | IGNORE_YAW_RATE   # 0x9F8
TYPE_MASK_VELOCITY_YAW = IGNORE_POSITION | IGNORE_ACCEL | IGNORE_YAW_RATE   # 0x9C7


class SetpointRejected(ValueError):
    """A setpoint failed validation; ``reason`` is a short machine-readable code."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class PositionSetpoint:
    """Target position in PX4's local NED frame (metres; z is negative up). yaw in rad,
    None to leave the heading to PX4."""
    x: float
    y: float
    z: float
    yaw: float | None = None

    @property
    def type_mask(self) -> int:
        return TYPE_MASK_POSITION_YAW | (IGNORE_YAW if self.yaw is None else 0)

    def values(self) -> tuple[float, ...]:
        return (self.x, self.y, self.z) + (() if self.yaw is None else (self.yaw,))


@dataclass(frozen=True, slots=True)
class VelocitySetpoint:
    """Target velocity in local NED (m/s). yaw in rad, None to leave it to PX4."""
    vx: float
    vy: float
    vz: float
    yaw: float | None = None

    @property
    def type_mask(self) -> int:
        return TYPE_MASK_VELOCITY_YAW | (IGNORE_YAW if self.yaw is None else 0)

    @property
    def speed(self) -> float:
        return math.sqrt(self.vx ** 2 + self.vy ** 2 + self.vz ** 2)

    def values(self) -> tuple[float, ...]:
        return (self.vx, self.vy, self.vz) + (() if self.yaw is None else (self.yaw,))


OffboardSetpoint = PositionSetpoint | VelocitySetpoint
Setpoint = OffboardSetpoint  # deprecated alias: collides with zenoh_robot.msgs.Setpoint


def mavlink_fields(sp: OffboardSetpoint) -> dict[str, float | int]:
    """Keyword arguments for set_position_target_local_ned_encode (minus ids and time)."""
    f: dict[str, float | int] = dict(coordinate_frame=MAV_FRAME_LOCAL_NED, type_mask=sp.type_mask,
                                     x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0,
                                     afx=0.0, afy=0.0, afz=0.0, yaw=0.0, yaw_rate=0.0)
    if isinstance(sp, PositionSetpoint):
        f.update(x=sp.x, y=sp.y, z=sp.z)
    else:
        f.update(vx=sp.vx, vy=sp.vy, vz=sp.vz)
    if sp.yaw is not None:
        f["yaw"] = sp.yaw
    return f


@dataclass(frozen=True, slots=True)
class Geofence:
    """Where position setpoints may go, relative to the local origin (PX4 home/EKF origin).

    Any limit set to None is not checked. Altitude is -z (up positive).
    """
    max_distance_m: float | None = 100.0        # horizontal radius around the origin
    max_altitude_m: float | None = 50.0
    min_altitude_m: float | None = None         # e.g. -1.0 to forbid setpoints below ground
    x_range: tuple[float, float] | None = None  # optional box, north (m)
    y_range: tuple[float, float] | None = None  # optional box, east (m)

    def violation(self, x: float, y: float, z: float) -> str | None:
        """Why (x, y, z) is outside the fence, or None when inside."""
        if not all(math.isfinite(v) for v in (x, y, z)):
            return f"non-finite position ({x}, {y}, {z})"   # NaN compares False: refuse
        alt = -z
        dist = math.hypot(x, y)
        if self.max_distance_m is not None and dist > self.max_distance_m:
            return f"{dist:.1f} m from origin exceeds geofence radius {self.max_distance_m:g} m"
        if self.max_altitude_m is not None and alt > self.max_altitude_m:
            return f"altitude {alt:.1f} m exceeds geofence ceiling {self.max_altitude_m:g} m"
        if self.min_altitude_m is not None and alt < self.min_altitude_m:
            return f"altitude {alt:.1f} m below geofence floor {self.min_altitude_m:g} m"
        if self.x_range is not None and not self.x_range[0] <= x <= self.x_range[1]:
            return f"x={x:.1f} m outside geofence box {self.x_range}"
        if self.y_range is not None and not self.y_range[0] <= y <= self.y_range[1]:
            return f"y={y:.1f} m outside geofence box {self.y_range}"
        return None


class SetpointValidator:
    """Stateful checks: the jump check needs the previously accepted setpoint.

    Jump rule: a position setpoint may lie at most ``max_speed * dt`` from the reference,
    where dt is the time since the previous accepted position setpoint clamped to
    [min_dt, 1 s]. The reference is that previous setpoint when it is younger than 1 s,
    otherwise the vehicle's latest position (if known). So a stream may move the target at
    up to max_speed, and a fresh target may be at most max_speed * 1 s from the vehicle.
    Velocity setpoints are checked against max_speed directly.
    """

    STALE_S = 1.0

    def __init__(self, geofence: Geofence | None = None, max_speed: float | None = 10.0,
                 min_dt: float = 0.05) -> None:
        self.geofence = geofence
        self.max_speed = max_speed
        self.min_dt = min_dt
        self._last_pos: tuple[float, float, float] | None = None
        self._last_time: float | None = None

    def check(self, sp: OffboardSetpoint, now: float,
              vehicle_position: tuple[float, float, float] | None = None) -> None:
        """Raise SetpointRejected if ``sp`` must not be sent; records nothing."""
        if not isinstance(sp, (PositionSetpoint, VelocitySetpoint)):
            raise SetpointRejected("type", f"unsupported setpoint type {type(sp).__name__}")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in sp.values()):
            raise SetpointRejected("non_finite", f"setpoint has a non-finite value: {sp}")
        if isinstance(sp, VelocitySetpoint):
            if self.max_speed is not None and sp.speed > self.max_speed:
                raise SetpointRejected("too_fast", f"velocity {sp.speed:.1f} m/s exceeds "
                                                   f"max_speed {self.max_speed:g} m/s")
            return
        if self.geofence is not None:
            why = self.geofence.violation(sp.x, sp.y, sp.z)
            if why is not None:
                raise SetpointRejected("geofence", f"setpoint {sp} rejected: {why}")
        if self.max_speed is None:
            return
        ref: tuple[float, float, float] | None = None
        dt = self.STALE_S
        if self._last_pos is not None and self._last_time is not None \
                and now - self._last_time < self.STALE_S:
            ref = self._last_pos
            dt = max(now - self._last_time, self.min_dt)
        elif vehicle_position is not None:
            ref = vehicle_position
        elif self._last_pos is not None:
            ref = self._last_pos
        if ref is None:
            return
        if not all(math.isfinite(v) for v in ref):
            # NaN > allowed is False: a spoofed NaN position would disable the jump check.
            raise SetpointRejected("no_reference", f"setpoint {sp} rejected: the reference "
                                                   f"position {ref} is not finite")
        jump = math.dist((sp.x, sp.y, sp.z), ref)
        allowed = self.max_speed * dt
        if not jump <= allowed:
            raise SetpointRejected(
                "too_fast", f"setpoint {sp} jumps {jump:.1f} m in {dt:.2f} s "
                            f"({jump / dt:.1f} m/s > max_speed {self.max_speed:g} m/s)")

    def accept(self, sp: OffboardSetpoint, now: float) -> None:
        """Record an accepted setpoint as the reference for the next jump check."""
        if isinstance(sp, PositionSetpoint):
            self._last_pos = (sp.x, sp.y, sp.z)
            self._last_time = now
