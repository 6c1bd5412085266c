"""The PX4 parameters the simulator honours, with PX4's defaults and types.

Defaults checked against PX4-Autopilot (commander_params.yaml, mc_pos_control params):
COM_OF_LOSS_T 1.0 s, COM_OBL_RC_ACT 0 (Position mode), COM_DISARM_PRFLT 10 s,
COM_DISARM_LAND 2 s, COM_FAIL_ACT_T 5 s, MIS_TAKEOFF_ALT 2.5 m, COM_SPOOLUP_TIME 1 s,
MPC_TKO_RAMP_T 3 s.
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
