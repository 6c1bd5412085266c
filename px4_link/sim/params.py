"""The PX4 parameters the simulator honours, with PX4's defaults and types.

Defaults checked against PX4-Autopilot (commander_params.yaml, mc_pos_control params):
COM_OF_LOSS_T 1.0 s, COM_OBL_RC_ACT 0 (Position mode), COM_DISARM_PRFLT 10 s,
COM_DISARM_LAND 2 s, COM_FAIL_ACT_T 5 s, MIS_TAKEOFF_ALT 2.5 m, COM_SPOOLUP_TIME 1 s,
MPC_TKO_RAMP_T 3 s.
Failsafe parameters (px4_link/sim/failsafe.py), from commander_params.c, navigator/geofence_params.c
and lib/battery/module.yaml: GF_ACTION 2 (Hold), GF_MAX_HOR_DIST / GF_MAX_VER_DIST 0 (off),
BAT_LOW_THR 0.15, BAT_CRIT_THR 0.07, BAT_EMERGEN_THR 0.05, COM_LOW_BAT_ACT 0 (warning),
COM_DL_LOSS_T 10 s, NAV_DLL_ACT 0 (off), NAV_RCL_ACT 2 (Return), COM_DLL_EXCEPT / COM_RCL_EXCEPT 0.
COM_RC_IN_MODE is SITL's 1 (MAVLink only; PX4's firmware default is 3): ground/px4_params.txt of
the Zenoh traces.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

INT32 = "INT32"
REAL32 = "REAL32"


@dataclass(frozen=True, slots=True)
class ParamSpec:
    name: str
    default: float | int
    type: str
    description: str


PX4_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("COM_OF_LOSS_T", 1.0, REAL32, "offboard loss timeout (s)"),
    ParamSpec("COM_OBL_RC_ACT", 0, INT32, "offboard loss action: 0 position, 1 altitude, "
              "2 stabilized, 3 return, 4 land, 5 hold, 6 terminate, 7 disarm"),
    ParamSpec("COM_DISARM_PRFLT", 10.0, REAL32, "auto-disarm if no takeoff after arming (s), <=0 off"),
    ParamSpec("COM_DISARM_LAND", 2.0, REAL32, "auto-disarm after landing (s), <=0 off"),
    ParamSpec("COM_FAIL_ACT_T", 5.0, REAL32, "hold before RTL/land failsafe actions (s)"),
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, REAL32, "default takeoff altitude (m)"),
    ParamSpec("COM_SPOOLUP_TIME", 1.0, REAL32, "motor spool-up time after arming (s)"),
    ParamSpec("MPC_TKO_RAMP_T", 3.0, REAL32, "takeoff climb-rate ramp time (s)"),
    ParamSpec("MPC_XY_VEL_MAX", 12.0, REAL32, "max horizontal speed (m/s)"),
    ParamSpec("MPC_XY_CRUISE", 5.0, REAL32, "horizontal speed in auto modes (m/s)"),
    ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, REAL32, "max climb rate (m/s)"),
    ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, REAL32, "max descent rate (m/s)"),
    ParamSpec("MPC_ACC_HOR", 3.0, REAL32, "horizontal acceleration (m/s^2)"),
    ParamSpec("MPC_ACC_UP_MAX", 4.0, REAL32, "max upward acceleration (m/s^2)"),
    ParamSpec("MPC_ACC_DOWN_MAX", 3.0, REAL32, "max downward acceleration (m/s^2)"),
    ParamSpec("MPC_TKO_SPEED", 1.5, REAL32, "takeoff climb rate (m/s)"),
    ParamSpec("MPC_LAND_SPEED", 0.7, REAL32, "landing descent rate (m/s)"),
    ParamSpec("MPC_YAWRAUTO_MAX", 45.0, REAL32, "max yaw rate in auto/offboard (deg/s)"),
    ParamSpec("RTL_RETURN_ALT", 60.0, REAL32, "RTL return altitude above home (m)"),
    ParamSpec("GF_ACTION", 2, INT32, "geofence breach action: 0 none, 1 warning, 2 hold, 3 return, "
              "4 terminate, 5 land"),
    ParamSpec("GF_MAX_HOR_DIST", 0.0, REAL32, "max horizontal distance from home (m), 0 off"),
    ParamSpec("GF_MAX_VER_DIST", 0.0, REAL32, "max height above home (m), 0 off"),
    ParamSpec("BAT_LOW_THR", 0.15, REAL32, "battery low threshold (fraction)"),
    ParamSpec("BAT_CRIT_THR", 0.07, REAL32, "battery critical threshold (fraction)"),
    ParamSpec("BAT_EMERGEN_THR", 0.05, REAL32, "battery emergency threshold (fraction)"),
    ParamSpec("COM_LOW_BAT_ACT", 0, INT32, "battery failsafe: 0 warning, 2 land, 3 return at critical, "
              "land at emergency"),
    ParamSpec("COM_DL_LOSS_T", 10, INT32, "GCS connection loss timeout (s)"),
    ParamSpec("NAV_DLL_ACT", 0, INT32, "GCS connection loss action: 0 off, 1 hold, 2 return, 3 land, "
              "5 terminate, 6 disarm"),
    ParamSpec("COM_DLL_EXCEPT", 0, INT32, "modes without GCS loss failsafe: bit 0 mission, 1 auto, 2 offboard"),
    ParamSpec("NAV_RCL_ACT", 2, INT32, "manual control loss action: 1 hold, 2 return, 3 land, 5 terminate, "
              "6 disarm"),
    ParamSpec("COM_RCL_EXCEPT", 0, INT32, "modes without RC loss failsafe: bit 0 mission, 1 auto, 2 offboard"),
    ParamSpec("COM_RC_IN_MODE", 1, INT32, "manual control input: 0 RC, 1 MAVLink, 2-3 either, 4 none, ..."),
    ParamSpec("MAV_SYS_ID", 1, INT32, "MAVLink system id (read-only here: set with --sysid)"),
)


class ParamStore:
    """Thread-safe name -> value store; order is PX4's (sorted by name) for PARAM indices."""

    def __init__(self, overrides: dict[str, float | int] | None = None) -> None:
        self._specs = {p.name: p for p in sorted(PX4_PARAMS, key=lambda p: p.name)}
        self._values: dict[str, float | int] = {n: s.default for n, s in self._specs.items()}
        self._lock = threading.Lock()
        for name, value in (overrides or {}).items():
            self.set(name, value)

    def names(self) -> list[str]:
        return list(self._specs)

    def __contains__(self, name: str) -> bool:
        return name in self._specs

    def __getitem__(self, name: str) -> float | int:
        with self._lock:
            return self._values[name]

    def type_of(self, name: str) -> str:
        return self._specs[name].type

    def set(self, name: str, value: float | int) -> float | int:
        """Coerce to the parameter's type and store; KeyError for unknown names."""
        spec = self._specs[name]
        v: float | int = int(round(float(value))) if spec.type == INT32 else float(value)
        with self._lock:
            self._values[name] = v
        return v

    def as_dict(self) -> dict[str, float | int]:
        with self._lock:
            return dict(self._values)
