"""The GCS's end-of-run summary: per drone and stream, what was sent and what arrived, the flight's
path error; printed as a table, written as strict JSON (or one CSV row per stream) for offline analysis."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rich.console import Console

from drone_contract.link_protection import link_refusals

from .app import Gcs


def summarize(gcs: Gcs, profile: str) -> dict[str, Any]:
    out: dict[str, Any] = {"profile": profile, "pattern": gcs.config.pattern, "formation": gcs.config.formation,
                           "drones": {}}
    # Late copies left together and could be lost together: a starved repeater, not the link.
    out["repeater"] = gcs.node.repeater_stats()
    # Sealed telemetry this GCS refused (forged, replayed, an earlier start of its drone): None unsealed.
    out["link_refused"] = link_refusals(gcs.node.wire)
    # The rates asked of each drone (None: its own): received rates are judged against these.
    out["downlink_asked"] = {"sensor_rate_hz": gcs.config.sensor_rate_hz, "camera_rate_hz": gcs.config.camera_rate_hz}
    for d in gcs.drones.values():
        streams = {name: rec.summary().as_dict() for name, rec in d.streams.items()}
        for name in d.streams:
            streams[name]["lost_pct"] = d.lost_pct(name)
        out["drones"][d.id] = {
            "setpoints_sent": d.setpoints_sent, "streams": streams,
            "frames": d.image.frames, "frames_complete": d.image.complete,
            "frames_decoded": d.frames.decoded, "decode_cpu_s": d.frames.decode_s,
            "slot": list(d.slot), "pattern": d.pattern_name,
            "max_path_error_m": d.plan.max_path_error,
            # Against the drone's own (slot's) path, from when it joined it (gcs/planner.py, PATH_JOIN_M).
            "mean_path_error_m": d.plan.mean_path_error, "path_error_samples": d.plan.path_error_samples,
            "joined_path": d.plan.on_path,
            "final_state": d.state.to_dict() if d.state else None,
            "events": [e.to_dict() for e in d.events],
            # Silent streams and a second companion with this id (gcs/alerts.py), and that one's states dropped.
            "alerts": d.alerts.log, "alerts_now": d.alerts.now, "state_ignored": d.source.ignored,
            # Samples this GCS's own queues dropped, per stream (gcs/shedding.py): load here, not loss there.
            "shed_by_gcs": dict(d.shedding.dropped),
            # The sensor rate this GCS asked the drone down to when it could not keep up (gcs/decimation.py).
            "sensor_decimated": {"steps": d.decimation.steps, "rate_hz": d.decimation.last_hz}
            if d.decimation.steps else None,
            "downlink": gcs.downlink.status[d.id].as_dict()
            if gcs.downlink is not None and d.id in gcs.downlink.status else None,
            # Raw (seq, stamp, arrival) records for offline analysis (the experiment joins them
            # with the companion's to get exact delivered % over a time window).
            "logs": {"sent": {k: v.to_dict() for k, v in d.sent.items()},
                     "received": {k: v.to_dict() for k, v in d.streams.items()}},
        }
    return out


def write_record(summary: dict[str, Any], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() != ".csv":
        from zenoh_robot.tools.bag.schemas import jsonable  # strict JSON: NaN -> null
        if path.suffix.lower() == ".mcap":    # the flight log itself was written live (GcsExtras)
            path = path.with_suffix(".summary.json")
        path.write_text(json.dumps(jsonable(summary), indent=2, default=str, allow_nan=False))
        return
    import csv
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        fields = ["received", "unique", "lost_pct", "age_avg_ms", "age_p50_ms", "age_p99_ms", "age_max_ms",
                  "period_avg_ms", "period_max_ms", "longest_gap_ms", "rate_hz"]
        w.writerow(["profile", "drone", "stream", *fields])
        for drone, d in summary["drones"].items():
            for name, s in d["streams"].items():
                w.writerow([summary["profile"], drone, name, *(s.get(k) for k in fields)])


def print_summary(console: Console, summary: dict[str, Any]) -> None:
    from rich.table import Table
    t = Table(title=f"summary ({summary['profile']})")
    for col in ("drone", "stream", "received", "lost %", "age avg ms", "age p99 ms", "period avg ms"):
        t.add_column(col)
    for drone, d in summary["drones"].items():
        for name, s in d["streams"].items():
            t.add_row(drone, name, str(s["received"]), f"{s['lost_pct']:.1f}", f"{s['age_avg_ms']:.1f}",
                      f"{s['age_p99_ms']:.1f}", f"{s['period_avg_ms']:.1f}")
        console.print(f"{drone}: setpoints sent {d['setpoints_sent']}, frames {d['frames']} "
                      f"({d['frames_complete']} whole), largest distance from the path "
                      f"{d['max_path_error_m']:.2f} m (mean {d['mean_path_error_m']:.2f} m, against its own path)")
        for alert in d.get("alerts", []):
            console.print(f"{drone}: {alert}")
        shed = {k: v for k, v in d.get("shed_by_gcs", {}).items() if v}
        if shed:   # counted in "lost" above (those samples never reached the stream's record)
            console.print(f"{drone}: this GCS dropped " + ", ".join(f"{v:,} {k}" for k, v in shed.items())
                          + " samples itself (its queues full): that part of 'lost' is this GCS's load, not the link")
        if d.get("downlink"):
            asked = {k: v for k, v in summary.get("downlink_asked", {}).items() if v is not None}
            console.print(f"{drone}: downlink asked {asked}: {d['downlink']['status']} {d['downlink']['detail']}")
    console.print(t)
