"""Offboard position/velocity targets and the one validator they pass before anything reaches PX4.

PX4 flies whatever SET_POSITION_TARGET_LOCAL_NED says; a NaN, a typo of 1000 m or a
target far outside the test area is a crash. So every target is validated here, by
``TargetValidator`` (px4_link's own stream checks, and the companion's check against what
the vehicle is doing), and a refused one raises ``TargetRefused`` and is never sent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

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

Vec3 = tuple[float, float, float]


class TargetRefused(ValueError):
    """A target (or an offboard request) that will not be flown. ``reason`` is a short
    machine-readable code; the message says what was refused and why (value and limit),
    and is what the sender is told."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class PositionTarget:
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
class VelocityTarget:
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


Target = PositionTarget | VelocityTarget


def mavlink_fields(sp: Target) -> dict[str, float | int]:
    """Keyword arguments for set_position_target_local_ned_encode (minus ids and time)."""
    f: dict[str, float | int] = dict(coordinate_frame=MAV_FRAME_LOCAL_NED, type_mask=sp.type_mask,
                                     x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0,
                                     afx=0.0, afy=0.0, afz=0.0, yaw=0.0, yaw_rate=0.0)
    if isinstance(sp, PositionTarget):
        f.update(x=sp.x, y=sp.y, z=sp.z)
    else:
        f.update(vx=sp.vx, vy=sp.vy, vz=sp.vz)
    if sp.yaw is not None:
        f["yaw"] = sp.yaw
    return f


# PX4's own geofence parameters are GF_MAX_HOR_DIST (horizontal distance from home) and
# GF_MAX_VER_DIST (height above home); PX4 ships both off (0). The link bounds every target
# by default: a companion that forgets to configure a fence still has one.
DEFAULT_FENCE_RADIUS_M = 100.0
DEFAULT_FENCE_CEILING_M = 120.0   # the usual legal ceiling for small drones (EU open category)
DEFAULT_FENCE_FLOOR_M = 0.0       # never below home: the ground, unless a user lowers it


@dataclass(frozen=True, slots=True)
class StoppingModel:
    """How far the vehicle travels before it stands still, from a speed: it keeps going for
    ``reaction_s`` (the link's tick, the telemetry's age, the controller's lag), then brakes at
    ``brake_mps2`` (PX4's MPC_ACC_HOR default is 3 m/s^2).

    1 s of reaction: in the simulator's loop (velocity P gain 3, tilt lag 0.35 s) a 9.5 m/s
    stream then stops within 0.02 m of the fence with telemetry up to 0.2 s old (0.2 m at
    0.3 s); with 0.5 s it overshot by 1.0-1.8 m."""
    brake_mps2: float = 3.0
    reaction_s: float = 1.0

    def distance(self, speed: float) -> float:
        """Stopping distance from ``speed`` (m/s): v * reaction + v^2 / (2 a)."""
        v = max(speed, 0.0)
        return v * self.reaction_s + v * v / (2.0 * self.brake_mps2)

    def speed_within(self, distance: float) -> float:
        """The highest speed whose stopping distance is ``distance``: the inverse of ``distance``."""
        if distance <= 0.0:
            return 0.0
        a, t = self.brake_mps2, self.reaction_s
        return a * (math.sqrt(t * t + 2.0 * distance / a) - t)


@dataclass(frozen=True, slots=True)
class Geofence:
    """Where the vehicle may be sent, relative to the local origin (PX4 home / EKF origin).

    - ``max_distance_m``: horizontal radius around the origin (PX4's GF_MAX_HOR_DIST).
    - ``max_altitude_m``: the ceiling, height above the origin (PX4's GF_MAX_VER_DIST).
    - ``min_altitude_m``: the floor, the lowest height above the origin a target may ask for
      (0: never below home). It bounds targets, not the vehicle: a vehicle below it (taking off,
      landing with PX4's own land mode) is never pushed anywhere; it may only climb or hold.
    - ``x_range``/``y_range``: an optional box, north/east (m).

    Any limit set to None is not checked. Altitude is -z (NED, up positive). Position targets
    outside are refused (``violation``); velocity targets are bounded predictively
    (``fence_velocity``): their speed towards a boundary never exceeds the speed from which the
    vehicle can still stop before it, so a stream that points out stops the vehicle at the fence.
    """
    max_distance_m: float | None = DEFAULT_FENCE_RADIUS_M
    max_altitude_m: float | None = DEFAULT_FENCE_CEILING_M
    min_altitude_m: float | None = DEFAULT_FENCE_FLOOR_M
    x_range: tuple[float, float] | None = None
    y_range: tuple[float, float] | None = None

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

    def boundaries(self, position: Vec3, heading: Vec3) -> list[tuple[str, Vec3, float]]:
        """Each limit as (name, outward unit vector at ``position``, distance left to it; negative
        when already beyond). ``heading`` picks the radial direction at the origin itself."""
        x, y, z = position
        out: list[tuple[str, Vec3, float]] = []
        if self.max_distance_m is not None:
            r = math.hypot(x, y)
            if r > 1e-6:
                u: Vec3 = (x / r, y / r, 0.0)
            else:   # at the origin every horizontal direction is radial: the one flown is outward
                h = math.hypot(heading[0], heading[1])
                u = (heading[0] / h, heading[1] / h, 0.0) if h > 1e-9 else (1.0, 0.0, 0.0)
            out.append((f"radius {self.max_distance_m:g} m", u, self.max_distance_m - r))
        if self.max_altitude_m is not None:
            out.append((f"ceiling {self.max_altitude_m:g} m", (0.0, 0.0, -1.0), self.max_altitude_m + z))
        if self.min_altitude_m is not None:
            out.append((f"floor {self.min_altitude_m:g} m", (0.0, 0.0, 1.0), -z - self.min_altitude_m))
        if self.x_range is not None:
            out.append((f"box x <= {self.x_range[1]:g} m", (1.0, 0.0, 0.0), self.x_range[1] - x))
            out.append((f"box x >= {self.x_range[0]:g} m", (-1.0, 0.0, 0.0), x - self.x_range[0]))
        if self.y_range is not None:
            out.append((f"box y <= {self.y_range[1]:g} m", (0.0, 1.0, 0.0), self.y_range[1] - y))
            out.append((f"box y >= {self.y_range[0]:g} m", (0.0, -1.0, 0.0), y - self.y_range[0]))
        return out

    def fence_velocity(self, sp: VelocityTarget, position: Vec3,
                       stopping: StoppingModel) -> tuple[VelocityTarget, str | None]:
        """``sp`` bounded so the vehicle at ``position`` stops inside the fence, and why it was
        cut (None when it passes as is).

        For every boundary the component of ``sp`` towards it may be at most the speed from
        which the vehicle stops in the distance left (``stopping.speed_within``); beyond a
        boundary, none. Components pointing back inside, and along a boundary, pass: a
        vehicle at the fence can still fly along it or come home.
        """
        if not all(math.isfinite(v) for v in position):
            return replace(sp, vx=0.0, vy=0.0, vz=0.0), "vehicle position not finite: velocity not fenced, zero sent"
        v = [sp.vx, sp.vy, sp.vz]
        why: dict[str, str] = {}
        limits = self.boundaries(position, (sp.vx, sp.vy, sp.vz))
        # Two passes: a cut towards one boundary can add speed towards a neighbouring one that
        # is not orthogonal (the radius and a box side).
        for _ in range(2):
            for name, u, left in limits:
                towards = v[0] * u[0] + v[1] * u[1] + v[2] * u[2]
                allowed = stopping.speed_within(left)
                if towards > allowed + 1e-9:
                    cut = towards - allowed
                    v = [v[i] - cut * u[i] for i in range(3)]
                    why.setdefault(name, f"{towards:.1f} m/s towards the {name} ({max(left, 0.0):.1f} m left) "
                                         f"cut to {allowed:.1f} m/s")
        if not why:
            return sp, None
        return replace(sp, vx=v[0], vy=v[1], vz=v[2]), "; ".join(why.values())


@dataclass(frozen=True, slots=True)
class VehicleMotion:
    """Where the vehicle is and how fast it moves (local NED, m and m/s)."""
    position: Vec3
    velocity: Vec3


class TargetValidator:
    """Every check a target passes before PX4 may fly it. Not thread safe: one owner.

    Two rules for position targets, one per caller:

    - ``check`` (px4_link's stream): the geofence, and a step rule. A velocity target needs the
      vehicle's position when there is a fence (it is fenced on every send, ``fence_velocity``).
      A position target may
      lie at most ``max_speed * dt`` from the reference, where dt is the time since the
      previous accepted position target clamped to [min_dt, 1 s], or, when the targets carry their
      sender's time (``sent_at``), the time between them as sent if that is longer: after a fade, a
      lossy link delivers the stream's next target milliseconds after the last one before the fade,
      and the pattern moved on meanwhile (arrival spacing alone refused a square at 2 m/s as 12 m/s
      after a 300 ms fade). Only the spacing of one sender's own stamps counts, never their clock. The
      reference is that
      previous target when it is younger than 1 s, otherwise the vehicle's latest position
      (if known). So a stream may move the target at up to max_speed, and a fresh target
      may be at most max_speed * 1 s from the vehicle. Stateful: ``accept`` records the
      reference.
    - ``check_against_vehicle`` (the companion, with its live limits): a position target
      may lie at most ``max_offset_m`` plus one second of the vehicle's current speed from
      the vehicle. It compares with the vehicle, not with the previous target, so a
      restarted GCS that streams from the vehicle's position is accepted anywhere, and a
      stale target far away is refused, saying how far. Stateless.

    Both refuse non-finite values and velocity targets faster than max_speed.
    """

    STALE_S = 1.0

    def __init__(self, geofence: Geofence | None = None, max_speed: float | None = 10.0,
                 min_dt: float = 0.05) -> None:
        self.geofence = geofence
        self.max_speed = max_speed
        self.min_dt = min_dt
        self._last_pos: Vec3 | None = None
        self._last_time: float | None = None
        self._last_sent: float | None = None

    @staticmethod
    def _check_values(sp: Target, max_speed: float | None) -> None:
        """The checks every target passes, whoever asks: type, finite, velocity speed."""
        if not isinstance(sp, (PositionTarget, VelocityTarget)):
            raise TargetRefused("type", f"unsupported target type {type(sp).__name__} "
                                        "(PositionTarget or VelocityTarget)")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in sp.values()):
            raise TargetRefused("non_finite", f"target has a non-finite value: {sp}")
        if isinstance(sp, VelocityTarget) and max_speed is not None and sp.speed > max_speed:
            raise TargetRefused("too_fast", f"velocity {sp.speed:.1f} m/s exceeds max_speed {max_speed:g} m/s")

    def check(self, sp: Target, now: float, vehicle_position: Vec3 | None = None,
              sent_at: float | None = None) -> None:
        """Raise TargetRefused if px4_link must not stream ``sp``; records nothing. ``sent_at``: the
        sender's time of ``sp``, seconds on its own clock (the step rule's spacing, class doc)."""
        self._check_values(sp, self.max_speed)
        if isinstance(sp, VelocityTarget):
            # Fenced on every send, from where the vehicle is then (Geofence.fence_velocity): a
            # velocity is a motion, not a place, so it cannot be judged once here.
            if self.geofence is not None and (vehicle_position is None
                                              or not all(math.isfinite(v) for v in vehicle_position)):
                raise TargetRefused("no_position", f"velocity target {sp} refused: the geofence needs the "
                                                   "vehicle's position (LOCAL_POSITION_NED, under 1 s old)")
            return
        if self.geofence is not None:
            why = self.geofence.violation(sp.x, sp.y, sp.z)
            if why is not None:
                raise TargetRefused("geofence", f"target {sp} refused: {why}")
        if self.max_speed is None:
            return
        ref: Vec3 | None = None
        dt = self.STALE_S
        if self._last_pos is not None and self._last_time is not None \
                and now - self._last_time < self.STALE_S:
            ref = self._last_pos
            dt = max(now - self._last_time, self.min_dt)
            if sent_at is not None and self._last_sent is not None:
                dt = max(dt, min(sent_at - self._last_sent, self.STALE_S))
        elif vehicle_position is not None:
            ref = vehicle_position
        elif self._last_pos is not None:
            ref = self._last_pos
        if ref is None:
            return
        if not all(math.isfinite(v) for v in ref):
            # NaN > allowed is False: a spoofed NaN position would disable the jump check.
            raise TargetRefused("no_reference", f"target {sp} refused: the reference "
                                                f"position {ref} is not finite")
        jump = math.dist((sp.x, sp.y, sp.z), ref)
        allowed = self.max_speed * dt
        if not jump <= allowed:
            raise TargetRefused(
                "too_fast", f"target {sp} jumps {jump:.1f} m in {dt:.2f} s "
                            f"({jump / dt:.1f} m/s > max_speed {self.max_speed:g} m/s)")

    def accept(self, sp: Target, now: float, sent_at: float | None = None) -> None:
        """Record an accepted target as the reference for the next step check."""
        if isinstance(sp, PositionTarget):
            self._last_pos = (sp.x, sp.y, sp.z)
            self._last_time = now
            self._last_sent = sent_at

    def check_against_vehicle(self, sp: Target, vehicle: VehicleMotion | None, max_offset_m: float,
                              max_speed: float | None = None) -> None:
        """Raise TargetRefused unless the vehicle can fly to ``sp`` from where it is now.

        ``max_speed`` None uses the validator's own. ``vehicle`` None means its position is
        unknown (or stale): a position target is then refused.
        """
        limit = self.max_speed if max_speed is None else max_speed
        self._check_values(sp, limit)
        if isinstance(sp, VelocityTarget):
            return
        if vehicle is None or not all(math.isfinite(v) for v in vehicle.position):
            raise TargetRefused("no_position", f"vehicle position unknown: position target "
                                               f"{_fmt((sp.x, sp.y, sp.z))} needs LOCAL_POSITION_NED")
        speed = math.hypot(*vehicle.velocity) if all(math.isfinite(v) for v in vehicle.velocity) else 0.0
        allowed = max_offset_m + speed * 1.0
        jump = math.dist((sp.x, sp.y, sp.z), vehicle.position)
        if jump > allowed:
            raise TargetRefused("jump", f"jump {jump:.1f} m from vehicle position > {allowed:.0f} m "
                                        f"(max_offset_m {max_offset_m:g} + 1 s at {speed:.1f} m/s; "
                                        f"target {_fmt((sp.x, sp.y, sp.z))}, "
                                        f"vehicle at {_fmt(vehicle.position)})")


def _fmt(v: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{x:.1f}" for x in v) + ")"
