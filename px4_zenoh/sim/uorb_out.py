"""The uORB messages the simulated PX4 publishes, built from the MAVLink simulator's vehicle model.

One job: turn the commander's state (px4_link.sim.commander) and the point-mass airframe
(px4_link.sim.physics) into px4_msgs values with PX4's field conventions: times in µs since boot,
NED metres, ``nav_state`` / ``arming_state`` enums of VehicleStatus.msg, validity flags once the
estimator is up. ``UserIntention`` follows PX4's ``nav_state_user_intention`` (UserModeIntention.cpp).

Threading: called on the simulator's loop thread only, under its lock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from px4_link.sim.commander import ON_GROUND, USER_REASONS, Commander
from px4_link.sim.failsafe import Failsafes, battery_warning
from px4_link.sim.physics import PointMassQuad

# VehicleStatus.msg NAVIGATION_STATE_*, by the simulator's mode names (px4_link.modes).
NAV_STATE = {"MANUAL": 0, "ALTCTL": 1, "POSCTL": 2, "AUTO.MISSION": 3, "AUTO.LOITER": 4, "AUTO.RTL": 5,
             "POSCTL.SLOW": 6, "ACRO": 10, "TERMINATION": 13, "OFFBOARD": 14, "STABILIZED": 15,
             "AUTO.TAKEOFF": 17, "AUTO.LAND": 18, "AUTO.FOLLOW_TARGET": 19, "AUTO.PRECLAND": 20,
             "POSCTL.ORBIT": 21, **{f"EXTERNAL{i}": 22 + i for i in range(1, 9)}}
NAV_TERMINATION = 13
DISARMED, ARMED = 1, 2
# ARM_DISARM_REASON_* by the commander's disarm texts
REASON_COMMAND_EXTERNAL, REASON_LANDING, REASON_PREFLIGHT_INACTION, REASON_FAILSAFE = 4, 6, 7, 14
EARTH_RADIUS_M = 6378137.0
VEHICLE_TYPE_ROTARY_WING, MAV_TYPE_QUADROTOR = 1, 2


def nav_state(mode: str) -> int:
    return NAV_STATE.get(mode, 4)


class UserIntention:
    """PX4's user mode intention: the last mode a user (or a finished takeoff) chose, and after a
    disarm the mode PX4 returns to; a failsafe changes the mode, never the intention."""

    def __init__(self, initial: str) -> None:
        self.mode = initial
        self._seen = 0

    def update(self, commander: Commander) -> None:
        log = commander.mode_log
        for change in log[self._seen:]:
            if change.reason in USER_REASONS or change.reason.startswith("disarmed"):
                self.mode = change.new
        self._seen = len(log)


@dataclass
class VehicleView:
    """What the builders read: the commander, the airframe, the failsafes, home."""
    types: dict[str, type[Any]]
    commander: Commander
    vehicle: PointMassQuad
    failsafes: Failsafes
    home: tuple[float, float, float]
    sysid: int
    intention: UserIntention
    disarm_reason: int = 0
    offboard_signal_lost: bool = True

    @property
    def estimate_ok(self) -> bool:
        return self.commander.estimate_valid()

    def latlon(self) -> tuple[float, float, float]:
        lat0, lon0, alt0 = self.home
        n, e, d = (float(v) for v in self.vehicle.pos)
        lat = lat0 + math.degrees(n / EARTH_RADIUS_M)
        lon = lon0 + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        return lat, lon, alt0 - d

    # ------------------------------------------------------------ builders, one per topic
    def vehicle_status(self, t_us: int) -> Any:
        c = self.commander
        nav = nav_state(c.mode)
        # external modes (ext_commander / mode_management): who is in charge, what is listed
        mm = getattr(c, "mm", None)
        valid = sum(1 << v for v in NAV_STATE.values() if v < 23)
        can_set = valid & ~(1 << NAV_TERMINATION)
        in_charge, display = 0, nav
        if mm is not None:
            valid, can_set = mm.mode_status(valid, can_set)
            in_charge, display = mm.executor_in_charge(), mm.nav_state_display(nav)
        return self.types["VehicleStatus"](
            timestamp=t_us, arming_state=ARMED if c.armed else DISARMED, nav_state=nav,
            executor_in_charge=in_charge, valid_nav_states_mask=valid, can_set_nav_states_mask=can_set,
            nav_state_display=display, nav_state_user_intention=nav_state(self.intention.mode),
            latest_disarming_reason=self.disarm_reason, failsafe=c.failsafe,
            vehicle_type=VEHICLE_TYPE_ROTARY_WING, system_type=MAV_TYPE_QUADROTOR, system_id=self.sysid,
            component_id=1, gcs_connection_lost=self.failsafes.gcs_connection_lost, power_input_valid=True,
            pre_flight_checks_pass=c.can_arm_refusal() is None)

    def vehicle_land_detected(self, t_us: int) -> Any:
        landed = self.commander.landed_state == ON_GROUND
        return self.types["VehicleLandDetected"](
            timestamp=t_us, ground_contact=landed, maybe_landed=landed, landed=landed,
            has_low_throttle=not self.commander.armed, at_rest=landed, close_to_ground_or_skipped_check=True)

    def vehicle_control_mode(self, t_us: int) -> Any:
        c = self.commander
        offboard = c.mode == "OFFBOARD"
        auto = c.mode.startswith("AUTO.")
        # an external mode's default config_control_setpoint (ModeManagement.hpp setControlModeDefaults)
        external = c.mode.startswith("EXTERNAL")
        flying_modes = auto or offboard or external or c.mode == "POSCTL"
        return self.types["VehicleControlMode"](
            timestamp=t_us, flag_armed=c.armed, flag_multicopter_position_control_enabled=flying_modes,
            flag_control_auto_enabled=auto, flag_control_offboard_enabled=offboard,
            flag_control_position_enabled=flying_modes, flag_control_velocity_enabled=flying_modes,
            flag_control_altitude_enabled=flying_modes, flag_control_climb_rate_enabled=flying_modes,
            flag_control_acceleration_enabled=flying_modes, flag_control_attitude_enabled=True,
            flag_control_rates_enabled=True, flag_control_allocation_enabled=True,
            flag_control_termination_enabled=c.mode == "TERMINATION", source_id=nav_state(c.mode))

    def failsafe_flags(self, t_us: int) -> Any:
        bad = not self.estimate_ok
        return self.types["FailsafeFlags"](
            timestamp=t_us, mode_req_offboard_signal=1 << NAV_STATE["OFFBOARD"],
            attitude_invalid=not self.commander.sensors_up(), local_altitude_invalid=bad,
            local_position_invalid=bad, local_position_invalid_relaxed=bad, local_velocity_invalid=bad,
            global_position_invalid=bad, global_position_invalid_relaxed=bad, auto_mission_missing=True,
            offboard_control_signal_lost=self.offboard_signal_lost, home_position_invalid=bad,
            manual_control_signal_lost=True, gcs_connection_lost=self.failsafes.gcs_connection_lost,
            battery_warning=battery_warning(self.vehicle.battery.remaining, self.commander.params))

    def vehicle_local_position(self, t_us: int) -> Any:
        v, ok = self.vehicle, self.estimate_ok
        x, y, z = (float(a) for a in v.pos)
        vx, vy, vz = (float(a) for a in v.vel)
        return self.types["VehicleLocalPosition"](
            timestamp=t_us, timestamp_sample=t_us, xy_valid=ok, z_valid=ok, v_xy_valid=ok, v_z_valid=ok,
            x=x, y=y, z=z, vx=vx, vy=vy, vz=vz, z_deriv=vz, heading=float(v.yaw), heading_good_for_control=ok,
            xy_global=ok, z_global=ok, ref_timestamp=t_us if ok else 0, ref_lat=self.home[0], ref_lon=self.home[1],
            ref_alt=self.home[2], dist_bottom_valid=ok, dist_bottom=max(0.0, -z), eph=0.5, epv=0.8, evh=0.1,
            evv=0.1, vxy_max=math.inf, vz_max=math.inf, hagl_min=math.inf, hagl_max_z=math.inf,
            hagl_max_xy=math.inf)

    def vehicle_global_position(self, t_us: int) -> Any:
        lat, lon, alt = self.latlon()
        ok = self.estimate_ok
        return self.types["VehicleGlobalPosition"](
            timestamp=t_us, timestamp_sample=t_us, lat=lat, lon=lon, alt=alt, alt_ellipsoid=alt + 47.0,
            lat_lon_valid=ok, alt_valid=ok, eph=0.5, epv=0.8, terrain_alt=self.home[2], terrain_alt_valid=ok)

    def vehicle_attitude(self, t_us: int) -> Any:
        v = self.vehicle
        cr, sr = math.cos(v.roll / 2), math.sin(v.roll / 2)
        cp, sp = math.cos(v.pitch / 2), math.sin(v.pitch / 2)
        cy, sy = math.cos(v.yaw / 2), math.sin(v.yaw / 2)
        q = [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
             cr * cp * sy - sr * sp * cy]
        return self.types["VehicleAttitude"](timestamp=t_us, timestamp_sample=t_us, q=q, delta_q_reset=[0.0] * 4)

    def sensor_combined(self, t_us: int) -> Any:
        s = self.vehicle.imu(self.home[2])
        return self.types["SensorCombined"](
            timestamp=t_us, gyro_rad=[float(a) for a in s.gyro], gyro_integral_dt=4000,
            accelerometer_m_s2=[float(a) for a in s.accel], accelerometer_integral_dt=4000)

    def battery_status(self, t_us: int) -> Any:
        b = self.vehicle.battery
        volts = 16.8 - 0.02 * (100 - b.percent)
        return self.types["BatteryStatus"](
            timestamp=t_us, connected=True, voltage_v=volts, current_a=12.0 if self.commander.armed else 0.5,
            current_average_a=12.0 if self.commander.armed else 0.5, remaining=b.remaining, scale=1.0,
            time_remaining_s=math.nan, temperature=math.nan, cell_count=4, id=1, voltage_cell_v=[0.0] * 14,
            warning=battery_warning(b.remaining, self.commander.params))

    def vehicle_gps_position(self, t_us: int) -> Any:
        lat, lon, alt = self.latlon()
        vn, ve, vd = (float(a) for a in self.vehicle.vel)
        up = self.commander.sensors_up()
        return self.types["SensorGps"](
            timestamp=t_us, timestamp_sample=t_us, device_id=11862025, latitude_deg=lat, longitude_deg=lon,
            altitude_msl_m=alt, altitude_ellipsoid_m=alt + 47.0, s_variance_m_s=0.3, c_variance_rad=0.1,
            fix_type=3 if up else 0, eph=0.9, epv=1.78, hdop=0.7, vdop=1.1, vel_m_s=math.hypot(vn, ve),
            vel_n_m_s=vn, vel_e_m_s=ve, vel_d_m_s=vd, cog_rad=math.atan2(ve, vn), vel_ned_valid=up,
            satellites_used=16 if up else 0, heading=math.nan, heading_offset=math.nan)

    def command_ack(self, t_us: int, command: int, result: int, target_system: int, target_component: int,
                    result_param1: int = 0) -> Any:
        return self.types["VehicleCommandAck"](
            timestamp=t_us, command=command, result=result, result_param1=result_param1,
            target_system=target_system, target_component=target_component, from_external=False)
