"""The ranges a PX4 parameter written through the companion (the ``set_param`` command) must respect.

The allow-list (``param_allow``) says which parameters a GCS may write; this table says which
values. Bounds are PX4's own parameter metadata (PX4-Autopilot main, ``src/modules/mc_pos_control/
multicopter_*_params.yaml`` and ``src/modules/navigator/mission_params.yaml``), so a value PX4's
QGroundControl would flag is refused before it reaches the vehicle; where PX4 gives no upper bound
the companion sets one (marked below). A name an operator added to the allow-list with no range
here passes on finiteness alone (the command policy's check): the operator chose to widen it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Px4Range:
    lo: float
    hi: float
    unit: str
    source: str = "PX4"      # "PX4": PX4's metadata; otherwise why the companion's bound


PX4_RANGES: dict[str, Px4Range] = {
    "MPC_XY_VEL_MAX": Px4Range(0.0, 20.0, "m/s"),
    "MPC_XY_CRUISE": Px4Range(3.0, 20.0, "m/s"),
    "MPC_Z_VEL_MAX_UP": Px4Range(0.5, 8.0, "m/s"),
    "MPC_Z_VEL_MAX_DN": Px4Range(0.5, 4.0, "m/s"),
    "MPC_TKO_SPEED": Px4Range(1.0, 5.0, "m/s"),
    # PX4: min 0.6, no max; a landing faster than the fastest descent PX4 allows is no landing.
    "MPC_LAND_SPEED": Px4Range(0.6, 4.0, "m/s", "PX4 min; max: MPC_Z_VEL_MAX_DN's max"),
    # PX4: min 0, no max; the companion's takeoff command accepts at most 120 m (command_policy).
    "MIS_TAKEOFF_ALT": Px4Range(0.0, 120.0, "m", "PX4 min; max: the takeoff command's"),
}


def px4_param_refusal(name: str, value: float) -> str:
    """Why writing ``value`` to PX4 parameter ``name`` is refused, or "" (no range known: "")."""
    r = PX4_RANGES.get(name)
    if r is None:
        return ""
    if not (math.isfinite(value) and r.lo <= value <= r.hi):
        return f"set_param {name}: {value:g} outside {r.lo:g}..{r.hi:g} {r.unit} ({r.source})"
    return ""
