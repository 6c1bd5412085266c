"""A quadrotor as a point mass, plus the IMU it would feel.

Good enough to exercise a companion: it tracks position/velocity targets through a P
position loop and a P velocity loop with PX4-like speed and acceleration limits, sits on
the ground (z = 0 in NED), and falls when the motors stop. Attitude is not simulated as a
state; it is derived from the commanded acceleration (a multicopter tilts to accelerate),
which is all the IMU and ATTITUDE messages need to look plausible.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

G = 9.80665
# Earth magnetic field (gauss, NED) near PX4 SITL's default home in Zurich.
MAG_NED = np.array([0.216, 0.006, 0.424])


@dataclass(slots=True)
class Limits:
    xy_vel: float = 12.0
    z_vel_up: float = 3.0
    z_vel_dn: float = 1.5
    acc_xy: float = 3.0
    acc_up: float = 4.0
    acc_dn: float = 3.0
    yaw_rate: float = math.radians(45.0)


@dataclass(slots=True)
class Battery:
    """State of charge (0..1) of the 4S pack, draining ~1 %/min from boot: enough for a GCS to show
    something alive. ``set_level`` is the low-battery fault: the pack reads ``level`` from then on
    and keeps draining from there (PX4's lib/battery estimate is what the failsafe reads)."""
    remaining: float = 1.0
    drain_per_s: float = 0.01 / 60.0

    def step(self, dt: float) -> None:
        self.remaining = max(0.0, self.remaining - self.drain_per_s * dt)

    def set_level(self, level: float) -> None:
        self.remaining = min(max(level, 0.0), 1.0)

    @property
    def percent(self) -> int:
        """BATTERY_STATUS / SYS_STATUS battery_remaining: whole percent, 100 until the first 1 % is used."""
        return max(0, min(100, math.ceil(self.remaining * 100 - 1e-6)))


@dataclass(slots=True)
class Target:
    """What the flight controller asks of the airframe this step."""
    position: np.ndarray | None = None   # NED m
    velocity: np.ndarray | None = None   # NED m/s (feed-forward, or alone for velocity control)
    yaw: float | None = None
    max_up: float | None = None          # overrides of the vertical speed limits (takeoff/land)
    max_dn: float | None = None
    max_xy: float | None = None


@dataclass(slots=True)
class ImuSample:
    accel: np.ndarray   # body FRD specific force, m/s^2
    gyro: np.ndarray    # body rates, rad/s
    mag: np.ndarray     # gauss
    baro_alt: float     # m AMSL
    pressure_hpa: float
    temperature_c: float


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def euler_to_dcm(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body -> NED rotation (ZYX Euler)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([
        [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
        [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
        [-sp, sr * cp, cr * cp]])


class PointMassQuad:
    # PX4's MPC_XY_P is 0.95, but SITL (SIH) trails a 2 m/s setpoint by 2.8 m, so the whole
    # loop (estimator delay, attitude response, velocity PID) acts like a gain of ~0.6-0.7.
    # These three were fitted by replaying the trace's setpoints: the square's path error
    # then comes out at mean 0.24 m / max 0.9 m (SITL: 0.35-0.51 / 0.8-1.1), without
    # overshoot on a 5 m step.
    KP_XY = 0.6
    KP_Z = 1.0     # MPC_Z_P
    KV_XY = 3.0
    KV_Z = 4.0     # MPC_Z_VEL_P_ACC
    TAU_ACC = 0.35  # tilt response: a point mass with instant acceleration cuts no corners

    def __init__(self, rng: np.random.Generator, gyro_noise: float = 0.003,
                 accel_noise: float = 0.05, mag_noise: float = 0.002,
                 baro_noise: float = 0.05) -> None:
        self.pos = np.zeros(3)
        self.vel = np.zeros(3)
        self.acc = np.zeros(3)
        self._acc_cmd_filtered = np.zeros(3)
        self.yaw = 0.0
        self.roll = 0.0
        self.pitch = 0.0
        self.rates = np.zeros(3)
        self.on_ground = True
        self.rng = rng
        self.gyro_noise, self.accel_noise = gyro_noise, accel_noise
        self.mag_noise, self.baro_noise = mag_noise, baro_noise
        self.gyro_bias = rng.normal(0.0, 0.002, 3)
        self.battery = Battery()

    def reset_position(self, delta: np.ndarray) -> None:
        """An estimator reset: the local frame moves by ``delta`` (NED m). The vehicle stays where it
        is in the world; what PX4 reports (LOCAL_POSITION_NED, GLOBAL_POSITION_INT) jumps by delta."""
        self.pos = self.pos + np.asarray(delta, dtype=float)

    def step(self, dt: float, target: Target | None, limits: Limits) -> None:
        """Advance by dt. target None = motors off (disarmed): gravity only."""
        self.battery.step(dt)
        if target is None:
            acc = np.array([0.0, 0.0, G]) if not self.on_ground else np.zeros(3)
            self._acc_cmd_filtered = np.zeros(3)
            yaw_rate = 0.0
        else:
            acc, yaw_rate = self._control(dt, target, limits)
        self.vel = self.vel + acc * dt
        self.pos = self.pos + self.vel * dt
        # Ground contact: the ground holds the vehicle up and friction stops it sliding.
        if self.pos[2] >= 0.0:
            self.pos[2] = 0.0
            if self.vel[2] > 0.0:
                self.vel[2] = 0.0
            climbing = acc[2] < -1e-3
            if not climbing:
                self.vel[0] = self.vel[1] = 0.0
                acc = np.zeros(3)
            self.on_ground = not climbing
        else:
            self.on_ground = False
        self.acc = acc
        old = (self.roll, self.pitch, self.yaw)
        self.yaw = _wrap(self.yaw + yaw_rate * dt)
        # Tilt follows the horizontal acceleration expressed in the heading frame.
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        ax_h = cy * acc[0] + sy * acc[1]
        ay_h = -sy * acc[0] + cy * acc[1]
        lift = max(G - acc[2], 0.1)
        self.pitch = -math.atan2(ax_h, lift) if target is not None else 0.0
        self.roll = math.atan2(ay_h, lift) if target is not None else 0.0
        self.rates = np.array([(self.roll - old[0]) / dt, (self.pitch - old[1]) / dt,
                               _wrap(self.yaw - old[2]) / dt])

    def _control(self, dt: float, t: Target, lim: Limits) -> tuple[np.ndarray, float]:
        v_des = np.zeros(3) if t.velocity is None else np.array(t.velocity, dtype=float)
        if t.position is not None:
            err = np.asarray(t.position, dtype=float) - self.pos
            v_des = v_des + np.array([self.KP_XY * err[0], self.KP_XY * err[1], self.KP_Z * err[2]])
        max_xy = t.max_xy if t.max_xy is not None else lim.xy_vel
        h = math.hypot(v_des[0], v_des[1])
        if h > max_xy:
            v_des[0:2] *= max_xy / h
        up = t.max_up if t.max_up is not None else lim.z_vel_up
        dn = t.max_dn if t.max_dn is not None else lim.z_vel_dn
        v_des[2] = min(max(v_des[2], -up), dn)
        acc = (v_des - self.vel) * np.array([self.KV_XY, self.KV_XY, self.KV_Z])
        ha = math.hypot(acc[0], acc[1])
        if ha > lim.acc_xy:
            acc[0:2] *= lim.acc_xy / ha
        acc[2] = min(max(acc[2], -lim.acc_up), lim.acc_dn)
        alpha = min(1.0, dt / self.TAU_ACC)
        self._acc_cmd_filtered[:2] += (acc[:2] - self._acc_cmd_filtered[:2]) * alpha
        self._acc_cmd_filtered[2] = acc[2]  # thrust answers much faster than tilt
        acc = self._acc_cmd_filtered.copy()
        yaw_rate = 0.0
        if t.yaw is not None and math.isfinite(t.yaw):
            err_yaw = _wrap(t.yaw - self.yaw)
            yaw_rate = max(-lim.yaw_rate, min(lim.yaw_rate, 2.0 * err_yaw))
            if abs(err_yaw) < abs(yaw_rate) * dt:
                yaw_rate = err_yaw / dt
        return acc, yaw_rate

    def imu(self, home_alt: float) -> ImuSample:
        r = euler_to_dcm(self.roll, self.pitch, self.yaw)
        f_ned = self.acc - np.array([0.0, 0.0, G])   # specific force: at rest (0, 0, -g)
        accel = r.T @ f_ned + self.rng.normal(0.0, self.accel_noise, 3)
        gyro = self.rates + self.gyro_bias + self.rng.normal(0.0, self.gyro_noise, 3)
        mag = r.T @ MAG_NED + self.rng.normal(0.0, self.mag_noise, 3)
        alt = home_alt - self.pos[2] + float(self.rng.normal(0.0, self.baro_noise))
        pressure = 1013.25 * (1.0 - 2.25577e-5 * alt) ** 5.25588
        return ImuSample(accel, gyro, mag, alt, pressure, 35.0)
