"""The companion's end-of-run summary: one honest log line, and strict JSON on disk.

A companion that never heard PX4 says so instead of printing figures of nothing
(``lost nan %``); a figure that does not exist is ``null`` in the file, never ``NaN``
(which is no JSON: strict parsers, jq and browsers refuse it).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from zenoh_robot.tools.bag.schemas import jsonable


def summary_line(drone_id: str, connection: str, summary: dict[str, Any]) -> str:
    px4 = summary.get("px4", {})
    if not px4.get("ever_connected", True):
        return (f"companion {drone_id}: PX4 never connected on {connection} (no heartbeat): "
                "no telemetry, no setpoints forwarded")
    sp = summary["setpoints"]
    lost = sp.get("lost_pct")
    if not sp.get("unique"):
        received = "no setpoints received"
    elif lost is None or not math.isfinite(lost):
        received = f"setpoints received {sp['unique']}"
    else:
        received = f"setpoints received {sp['unique']} (lost {lost:.1f} %)"
    refused = summary.get("link_refused") or {}
    attack = ""
    if sum(refused.values()):
        why = ", ".join(f"{k} {v}" for k, v in sorted(refused.items(), key=lambda kv: -kv[1]) if v)
        attack = f", sealed samples refused {sum(refused.values())} ({why})"
    return (f"companion {drone_id}: {received}, rejected {summary['setpoints_rejected']}{attack}, "
            f"final mode {summary['final_mode'] or 'unknown'}")


def write_summary(path: Path, summary: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(jsonable(summary), indent=2, default=str, allow_nan=False))
