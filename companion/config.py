"""The companion's settings: one dataclass, every field also a node parameter (params.py)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drone_contract.limits import COMPANION_DEADLINE_S, CONTROL_LEASE_S, MAX_OFFSET_M, MAX_SPEED_MS
from drone_contract.streams import StreamProfile, stream_profile
from px4_link.targets import DEFAULT_FENCE_CEILING_M, DEFAULT_FENCE_FLOOR_M, DEFAULT_FENCE_RADIUS_M, Geofence

# Parameters a GCS may set by default: speeds and takeoff/landing behaviour, never failsafes or geofence.
DEFAULT_PARAM_ALLOW = ("MPC_XY_VEL_MAX", "MPC_XY_CRUISE", "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN",
                       "MPC_TKO_SPEED", "MPC_LAND_SPEED", "MIS_TAKEOFF_ALT")


@dataclass
class CompanionConfig:
    drone_id: str = "uav1"
    profile: StreamProfile = field(default_factory=lambda: stream_profile("resilient"))
    setpoint_deadline: float = COMPANION_DEADLINE_S
    resume_on_setpoints: bool = False
    sensor_rate_hz: float = 200.0        # the thesis's SensorCombined rate; asked of PX4 via MAVLink
    sensor_rate_tolerance: float = 0.9   # warn when PX4 delivers less than this share of it
    state_rate_hz: float = 5.0
    camera: str | None = "test"          # None: no images
    camera_rate_hz: float = 30.0
    image_width: int = 320
    image_height: int = 240
    max_offset_m: float = MAX_OFFSET_M   # how far a position target may lie from the vehicle
    max_speed: float = MAX_SPEED_MS      # velocity setpoints, m/s
    control_lease_s: float = CONTROL_LEASE_S   # a controller without liveliness token is gone after this silence
    # The geofence px4_link applies to every target (PX4's GF_MAX_HOR_DIST / GF_MAX_VER_DIST), around
    # home: position targets outside are refused, velocity targets cut so the vehicle stops at it.
    fence_radius_m: float = DEFAULT_FENCE_RADIUS_M    # horizontal distance from home
    fence_ceiling_m: float = DEFAULT_FENCE_CEILING_M  # height above home
    fence_floor_m: float = DEFAULT_FENCE_FLOOR_M      # lowest height above home a target may ask for
    allow_force_disarm: bool = False     # a forced disarm in flight drops the vehicle
    param_allow: tuple[str, ...] = DEFAULT_PARAM_ALLOW
    report_interval_s: float = 2.0       # repeated refusals: one event per key per interval
    px4_streams: str = "lean"            # lean: only the PX4 streams read (LEAN_STREAMS_HZ); default: PX4's
    mavlink_tunnel: bool = False         # a QGC reads PX4's streams through the tunnel: nothing is cut
    qos_overrides: dict[str, Any] = field(default_factory=dict)   # -p reliability/history/depth, as given

    def geofence(self) -> Geofence:
        """The fence px4_link applies, from the values in force."""
        return Geofence(max_distance_m=self.fence_radius_m, max_altitude_m=self.fence_ceiling_m,
                        min_altitude_m=self.fence_floor_m)
