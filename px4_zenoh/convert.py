"""uORB samples -> px4_link's telemetry types and vehicle state, so the companion reads one model.

Mode names are the ones px4_link decodes from MAVLink's custom_mode, mapped from
``vehicle_status.nav_state`` as PX4's own MAVLink module does (``px4_custom_mode.h``
get_px4_custom_mode), so logs, events and the summary read the same over either backend.

Where the uORB topic lacks a field the MAVLink message has, the value is said below: never NaN in a
field px4_link's finiteness check guards (the sample would be dropped), never invented motion.
"""
from __future__ import annotations

import math
from typing import Any

from px4_link.telemetry import PREARM_CHECK, Attitude, Battery, GlobalPosition, Imu, LocalPosition, SysStatus

ARMING_STATE_ARMED = 2
LANDED_ON_GROUND, LANDED_IN_AIR = 1, 2   # MAV_LANDED_STATE, as px4_link's Px4State.landed reads it

NAV_STATE_MODES: dict[int, str] = {
    0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO.MISSION", 4: "AUTO.LOITER", 5: "AUTO.RTL",
    6: "POSCTL.SLOW", 8: "ALTCTL", 10: "ACRO", 12: "AUTO.LAND", 13: "TERMINATION", 14: "OFFBOARD",
    15: "STABILIZED", 17: "AUTO.TAKEOFF", 18: "AUTO.LAND", 19: "AUTO.FOLLOW_TARGET", 20: "AUTO.PRECLAND",
    21: "POSCTL.ORBIT", 22: "AUTO.VTOL_TAKEOFF",
    # external modes (px4_zenoh.external_mode): PX4's NAVIGATION_STATE_EXTERNAL1..8
    **{22 + n: f"EXTERNAL{n}" for n in range(1, 9)},
}


def mode_of(nav_state: int) -> str:
    return NAV_STATE_MODES.get(nav_state, f"UNKNOWN(nav_state {nav_state})")


def imu(m: Any, sysid: int) -> Imu:
    """sensor_combined carries no magnetometer or barometer (separate uORB topics, not subscribed):
    those fields are 0."""
    g, a = m.gyro_rad, m.accelerometer_m_s2
    return Imu(int(m.timestamp), (g[0], g[1], g[2]), (a[0], a[1], a[2]), (0.0, 0.0, 0.0), 0.0, 0.0, 0.0,
               system_id=sysid)


def attitude(m: Any, sysid: int) -> Attitude:
    """Euler angles (ZYX) from vehicle_attitude's quaternion; the body rates are vehicle_angular_velocity's
    (not subscribed): 0."""
    w, x, y, z = m.q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return Attitude(int(m.timestamp) // 1000, roll, pitch, yaw, 0.0, 0.0, 0.0, system_id=sysid)


def local_position(m: Any, sysid: int) -> LocalPosition:
    return LocalPosition(int(m.timestamp) // 1000, m.x, m.y, m.z, m.vx, m.vy, m.vz, system_id=sysid)


def global_position(m: Any, local: LocalPosition | None, sysid: int) -> GlobalPosition:
    """vehicle_global_position has no height above home nor velocity: both come from the latest local
    position (origin = EKF origin = home on the ground), 0 until there is one."""
    rel = -local.z if local is not None else 0.0
    v = local.velocity if local is not None else (0.0, 0.0, 0.0)
    return GlobalPosition(int(m.timestamp) // 1000, m.lat, m.lon, float(m.alt), rel, v[0], v[1], v[2], None,
                          system_id=sysid)


def battery(m: Any, sysid: int) -> Battery:
    remaining = m.remaining * 100.0 if m.remaining >= 0 else math.nan
    return Battery(int(m.id), m.voltage_v, m.current_a, remaining, m.discharged_mah, m.temperature,
                   system_id=sysid)


def sys_status(status: Any, sysid: int) -> SysStatus:
    """The pre-arm verdict (``pre_flight_checks_pass``) as MAVLink's PREARM_CHECK health bit; the rest
    SYS_STATUS carries has no uORB source here (NaN / 0)."""
    bit = PREARM_CHECK if status.pre_flight_checks_pass else 0
    return SysStatus(PREARM_CHECK, PREARM_CHECK, bit, math.nan, math.nan, math.nan, math.nan, 0.0, 0,
                     system_id=sysid)
