"""A flown cell's flight figures, from its raw records (issue #29: measured on drones that fly).

Inputs, all kept in the cell's directory: the companion's vehicle record (``companion
--vehicle-record``: every 20 ms PX4's mode, armed, position and the source stamp of the target
px4_link streams to PX4), the companion's summary (failsafes) and the GCS's summary (its mission's
steps). Out: time in OFFBOARD over the time asked, the age of the target the vehicle is given (the
gap that matters: px4_link re-streams whatever it was last given at 20 Hz, so PX4's own stream
never gaps), path error against the commanded pattern, and the mission's commands through the real
companion with their latency.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from gcs.patterns import path_distance

OFFBOARD_GAP_MS = 500.0     # PX4 leaves OFFBOARD when setpoints stop for longer (the 2 Hz rule)
SAMPLE_MS = 20.0            # the vehicle record's period: a sampled age is under by at most this
# Mission steps whose latency is "step done - when the mission asked": the step before it, plus the
# mission's own wait (gcs/mission.py: 0.3 s of setpoints before offboard_start; the pattern's end
# before land is the climb's end + the pattern's duration).
COMMAND_STEPS = {"offboard_start": ("drone connected", 0.3), "arm": ("armable", 0.0)}


def load_vehicle(path: Path) -> list[dict[str, Any]]:
    """The vehicle record's samples (a line cut by the process's end is skipped)."""
    out: list[dict[str, Any]] = []
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


def _q(values: list[float], p: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(p * len(s)))] if s else math.nan


def target_age(samples: list[dict[str, Any]], t0: int, t1: int) -> dict[str, Any]:
    """The age of the target PX4 is given (now - its GCS source stamp) over [t0, t1]: max, p99, how
    often it went over PX4's 500 ms, and the longest time without a new target."""
    inside = [s for s in samples if t0 <= s["t"] <= t1 and s.get("sp_stamp")]
    if not inside:
        return {"samples": 0, "age_max_ms": None, "age_p99_ms": None, "stale_over_500ms": None,
                "longest_no_new_target_ms": None}
    ages = [(s["t"] - s["sp_stamp"]) / 1e6 for s in inside]
    over = sum(1 for a, b in zip(ages, ages[1:], strict=False) if a <= OFFBOARD_GAP_MS < b)
    over += ages[0] > OFFBOARD_GAP_MS
    changes = [inside[0]["t"]] + [b["t"] for a, b in zip(inside, inside[1:], strict=False)
                                  if b["sp_stamp"] != a["sp_stamp"]] + [inside[-1]["t"]]
    longest = max((b - a) / 1e6 for a, b in zip(changes, changes[1:], strict=False)) if len(changes) > 1 else 0.0
    return {"samples": len(inside), "age_max_ms": round(max(ages), 1), "age_p99_ms": round(_q(ages, 0.99), 1),
            "stale_over_500ms": over, "longest_no_new_target_ms": round(longest, 1)}


def offboard_share(samples: list[dict[str, Any]], t0: int, t1: int) -> float | None:
    """Share of [t0, t1] PX4 spent armed in OFFBOARD (None: no sample in it)."""
    inside = [s for s in samples if t0 <= s["t"] <= t1]
    if not inside:
        return None
    return round(sum(1 for s in inside if s.get("mode") == "OFFBOARD" and s.get("armed")) / len(inside), 4)


def path_error(samples: list[dict[str, Any]], t0: int, t1: int, pattern: str, size: float) -> dict[str, Any]:
    """Horizontal distance from the vehicle to the commanded pattern's path over [t0, t1]."""
    d = [path_distance(s["pos"][0], s["pos"][1], pattern, size) for s in samples
         if t0 <= s["t"] <= t1 and s.get("pos")]
    if not d:
        return {"samples": 0, "mean_m": None, "max_m": None}
    return {"samples": len(d), "mean_m": round(sum(d) / len(d), 3), "max_m": round(max(d), 3)}


def mission_commands(steps: list[dict[str, Any]], pattern_s: float) -> dict[str, dict[str, Any]]:
    """offboard_start, arm and land as the mission sent them through the real companion: success and
    latency (s, from the mission's step times: within its 0.1-0.2 s polling)."""
    at = {s["step"]: s for s in steps}
    out: dict[str, dict[str, Any]] = {}
    for name, (before, wait) in COMMAND_STEPS.items():
        if name in at and before in at:
            out[name] = {"ok": bool(at[name]["ok"]), "s": round(at[name]["t"] - at[before]["t"] - wait, 3),
                         "detail": at[name].get("detail", "")}
    if "land" in at and "climb" in at:
        out["land"] = {"ok": bool(at["land"]["ok"]), "s": round(at["land"]["t"] - at["climb"]["t"] - pattern_s, 3),
                       "detail": at["land"].get("detail", "")}
    return out


def flight_figures(workdir: Path, window: tuple[int, int], pattern: str, size: float,
                   pattern_s: float, drone_id: str) -> dict[str, Any]:
    """Everything the flight says, for the cell's result (``flight``)."""
    samples = load_vehicle(workdir / "vehicle.jsonl")
    try:
        gcs = json.loads((workdir / "gcs.json").read_text())
    except (OSError, ValueError):
        gcs = {}
    try:
        drone = json.loads((workdir / "drone.json").read_text())
    except (OSError, ValueError):
        drone = {}
    mission = gcs.get("mission") or {}
    steps = list(mission.get("steps") or [])
    t0, t1 = window
    in_window = [s for s in samples if t0 <= s["t"] <= t1]
    flown = [s for s in steps if s["step"] == "climb" and s["ok"]]
    pattern_span = (int(flown[0]["t"] * 1e9), int(flown[0]["t"] * 1e9 + pattern_s * 1e9)) if flown else None
    # Asked: from armed (in OFFBOARD) to the land command at the pattern's end (OFFBOARD all that time).
    armed = [s for s in steps if s["step"] == "arm" and s["ok"]]
    asked_span = (int(armed[0]["t"] * 1e9), pattern_span[1]) if armed and pattern_span else None
    failsafe = drone.get("failsafe") or {}
    return {
        "mission_ok": bool(mission.get("ok")), "mission_result": mission.get("result", "no mission record"),
        "armed_in_window": bool(in_window) and all(s.get("armed") for s in in_window),
        "offboard_share_window": offboard_share(samples, t0, t1),
        "offboard_share_asked": offboard_share(samples, *asked_span) if asked_span else None,
        "failsafes": failsafe.get("triggered"), "holds": failsafe.get("holds"),
        "offboard_state_final": drone.get("offboard_state"),
        "vehicle_target": target_age(samples, t0, t1),
        "path_error_window": path_error(samples, t0, t1, pattern, size),
        "path_error_pattern": path_error(samples, *pattern_span, pattern, size) if pattern_span else
        {"samples": 0, "mean_m": None, "max_m": None},
        "gcs_max_path_error_m": ((gcs.get("drones") or {}).get(drone_id) or {}).get("max_path_error_m"),
        "commands": mission_commands(steps, pattern_s),
        "vehicle_samples": len(samples),
    }
