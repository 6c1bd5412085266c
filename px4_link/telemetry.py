"""Telemetry as plain dataclasses, decoded from PX4's MAVLink messages.

Users of the link should never need pymavlink objects: every value here is in SI units
(except where the field name says otherwise) and every instance carries the vehicle's
system id and the local monotonic time it was received, so consumers can compute age.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

Vec3 = tuple[float, float, float]

# MAV_LANDED_STATE
LANDED_STATE_NAMES = {0: "UNDEFINED", 1: "ON_GROUND", 2: "IN_AIR", 3: "TAKEOFF", 4: "LANDING"}
# MAV_SYS_STATUS_PREARM_CHECK: PX4 sets it in onboard_control_sensors_health while its pre-arm
# checks pass (HealthAndArmingChecks; real SITL: from ~4.1 s after boot, never in present).
PREARM_CHECK = 0x10000000
# MAV_STATE
SYSTEM_STATUS_NAMES = {0: "UNINIT", 1: "BOOT", 2: "CALIBRATING", 3: "STANDBY", 4: "ACTIVE",
                       5: "CRITICAL", 6: "EMERGENCY", 7: "POWEROFF", 8: "FLIGHT_TERMINATION"}


def _now() -> float:
    return time.monotonic()


@dataclass(frozen=True, slots=True)
class Imu:
    """HIGHRES_IMU: what PX4's uORB SensorCombined carries, with SensorCombined field names."""
    timestamp_us: int
    gyro_rad: Vec3
    accelerometer_m_s2: Vec3
    magnetometer_ga: Vec3
    baro_alt_meter: float
    baro_temp_celcius: float  # (sic) PX4's historical spelling, kept so fields map 1:1
    abs_pressure_hpa: float
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @classmethod
    def from_mavlink(cls, m: Any) -> "Imu":
        return cls(
            timestamp_us=int(m.time_usec),
            gyro_rad=(m.xgyro, m.ygyro, m.zgyro),
            accelerometer_m_s2=(m.xacc, m.yacc, m.zacc),
            magnetometer_ga=(m.xmag, m.ymag, m.zmag),
            baro_alt_meter=m.pressure_alt,
            baro_temp_celcius=m.temperature,
            abs_pressure_hpa=m.abs_pressure,
            system_id=m.get_srcSystem(),
        )


@dataclass(frozen=True, slots=True)
class Attitude:
    """ATTITUDE: Euler angles (rad) and body rates (rad/s)."""
    time_boot_ms: int
    roll: float
    pitch: float
    yaw: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @classmethod
    def from_mavlink(cls, m: Any) -> "Attitude":
        return cls(m.time_boot_ms, m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed,
                   m.yawspeed, system_id=m.get_srcSystem())


@dataclass(frozen=True, slots=True)
class LocalPosition:
    """LOCAL_POSITION_NED: metres and m/s in PX4's local NED frame (origin = EKF origin)."""
    time_boot_ms: int
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @property
    def position(self) -> Vec3:
        return (self.x, self.y, self.z)

    @property
    def velocity(self) -> Vec3:
        return (self.vx, self.vy, self.vz)

    @classmethod
    def from_mavlink(cls, m: Any) -> "LocalPosition":
        return cls(m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz, system_id=m.get_srcSystem())


@dataclass(frozen=True, slots=True)
class GlobalPosition:
    """GLOBAL_POSITION_INT converted from its integer encodings."""
    time_boot_ms: int
    lat_deg: float
    lon_deg: float
    alt_m: float            # AMSL
    relative_alt_m: float   # above home
    vx: float               # m/s, north
    vy: float
    vz: float
    heading_deg: float | None
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @classmethod
    def from_mavlink(cls, m: Any) -> "GlobalPosition":
        heading = None if m.hdg == 65535 else m.hdg / 100.0
        return cls(m.time_boot_ms, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0,
                   m.relative_alt / 1000.0, m.vx / 100.0, m.vy / 100.0, m.vz / 100.0, heading,
                   system_id=m.get_srcSystem())


@dataclass(frozen=True, slots=True)
class Battery:
    """BATTERY_STATUS: pack voltage summed from the cell array, NaN where unknown."""
    battery_id: int
    voltage_v: float
    current_a: float
    remaining_pct: float
    consumed_mah: float
    temperature_c: float
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @classmethod
    def from_mavlink(cls, m: Any) -> "Battery":
        cells = [v for v in m.voltages if v != 65535]
        voltage = sum(cells) / 1000.0 if cells else math.nan
        current = m.current_battery / 100.0 if m.current_battery != -1 else math.nan
        remaining = float(m.battery_remaining) if m.battery_remaining != -1 else math.nan
        consumed = float(m.current_consumed) if m.current_consumed != -1 else math.nan
        temp = m.temperature / 100.0 if m.temperature != 32767 else math.nan
        return cls(m.id, voltage, current, remaining, consumed, temp, system_id=m.get_srcSystem())


@dataclass(frozen=True, slots=True)
class SysStatus:
    """SYS_STATUS: sensor health bitmasks, CPU load and link drop rate."""
    sensors_present: int
    sensors_enabled: int
    sensors_health: int
    load_pct: float
    voltage_battery_v: float
    current_battery_a: float
    battery_remaining_pct: float
    drop_rate_comm_pct: float
    errors_comm: int
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @classmethod
    def from_mavlink(cls, m: Any) -> "SysStatus":
        return cls(
            m.onboard_control_sensors_present, m.onboard_control_sensors_enabled,
            m.onboard_control_sensors_health, m.load / 10.0,
            m.voltage_battery / 1000.0 if m.voltage_battery != 65535 else math.nan,
            m.current_battery / 100.0 if m.current_battery != -1 else math.nan,
            float(m.battery_remaining) if m.battery_remaining != -1 else math.nan,
            m.drop_rate_comm / 100.0, m.errors_comm, system_id=m.get_srcSystem())

    @property
    def armable(self) -> bool:
        """PX4's pre-arm checks pass (the PREARM_CHECK health bit)."""
        return bool(self.sensors_health & PREARM_CHECK)


@dataclass(frozen=True, slots=True)
class ExtendedSysState:
    """EXTENDED_SYS_STATE: PX4's land detector output."""
    landed_state: int
    vtol_state: int
    system_id: int = 0
    received_at: float = field(default_factory=_now)

    @property
    def landed_state_name(self) -> str:
        return LANDED_STATE_NAMES.get(self.landed_state, f"UNKNOWN({self.landed_state})")

    @classmethod
    def from_mavlink(cls, m: Any) -> "ExtendedSysState":
        return cls(m.landed_state, m.vtol_state, system_id=m.get_srcSystem())


@dataclass(frozen=True, slots=True)
class Px4State:
    """What the link knows about the vehicle, mostly from its HEARTBEAT."""
    connected: bool = False
    system_id: int | None = None
    component_id: int | None = None
    mode: str = "UNKNOWN"
    # An external mode's registered name (PX4's AVAILABLE_MODES: ``mode`` says EXTERNAL<n>); None for
    # PX4's own modes, or before the list names it.
    mode_name: str | None = None
    # The PX4 mode that external mode flies in place of (a companion's RTL replacing PX4's: "AUTO.RTL"), when
    # its owner says so (VehicleCore.add_mode_namer); None otherwise.
    mode_replaces: str | None = None
    custom_mode: int = 0
    base_mode: int = 0
    armed: bool = False
    landed_state: int = 0
    system_status: int = 0
    autopilot: int | None = None
    vehicle_type: int | None = None
    last_heartbeat: float | None = None  # monotonic
    heartbeats: int = 0

    @property
    def landed(self) -> bool | None:
        """True on ground, False in the air, None before EXTENDED_SYS_STATE says."""
        if self.landed_state == 1:
            return True
        if self.landed_state in (2, 3, 4):
            return False
        return None

    @property
    def landed_state_name(self) -> str:
        return LANDED_STATE_NAMES.get(self.landed_state, f"UNKNOWN({self.landed_state})")

    @property
    def system_status_name(self) -> str:
        return SYSTEM_STATUS_NAMES.get(self.system_status, f"UNKNOWN({self.system_status})")


Telemetry = Imu | Attitude | LocalPosition | GlobalPosition | Battery | SysStatus | ExtendedSysState

# MAVLink message name -> decoder. The link dispatches on this table only.
DECODERS: dict[str, Callable[[Any], Any]] = {
    "HIGHRES_IMU": Imu.from_mavlink,
    "ATTITUDE": Attitude.from_mavlink,
    "LOCAL_POSITION_NED": LocalPosition.from_mavlink,
    "GLOBAL_POSITION_INT": GlobalPosition.from_mavlink,
    "BATTERY_STATUS": Battery.from_mavlink,
    "SYS_STATUS": SysStatus.from_mavlink,
    "EXTENDED_SYS_STATE": ExtendedSysState.from_mavlink,
}

TELEMETRY_TYPES: tuple[type, ...] = (Imu, Attitude, LocalPosition, GlobalPosition, Battery,
                                     SysStatus, ExtendedSysState)


# Fields that must be finite for a sample to reach listeners. Battery/SysStatus use NaN
# for "unknown" on purpose, so only their scalar ids are checked implicitly (ints).
_FINITE_FIELDS: dict[type, tuple[str, ...]] = {
    Imu: ("gyro_rad", "accelerometer_m_s2", "magnetometer_ga", "baro_alt_meter",
          "abs_pressure_hpa"),
    Attitude: ("roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed"),
    LocalPosition: ("x", "y", "z", "vx", "vy", "vz"),
    GlobalPosition: ("lat_deg", "lon_deg", "alt_m", "relative_alt_m", "vx", "vy", "vz"),
}


def is_finite_sample(sample: Any) -> bool:
    """False when a field a consumer would act on is NaN/inf (never sensor data)."""
    for name in _FINITE_FIELDS.get(type(sample), ()):
        v = getattr(sample, name)
        values = v if isinstance(v, tuple) else (v,)
        if not all(math.isfinite(x) for x in values):
            return False
    return True
