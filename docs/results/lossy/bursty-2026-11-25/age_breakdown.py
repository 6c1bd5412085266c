"""Where a flown cell's target ages come from: `python age_breakdown.py RESULTS_DIR [CELL ...]`.

For every time the target at the vehicle (the companion's vehicle record, every 20 ms) was older than
``--over`` ms before a new one replaced it, inside the cell's window: the previous target's age when it
reached the companion (the GCS's 10 Hz phase: the last packet before a fade carries a sample up to one
period old), the gap between arrivals at the companion, the arrival-to-vehicle delay (forwarding, within
one record period), whether the new target was the newest the GCS had published (latest wins), and the
fades (bursty channel's bad periods) the gap lay in. Reads only the cell's kept raw records.
"""
from __future__ import annotations

import argparse
import json
import lzma
from pathlib import Path
from typing import Any


def _load(path: Path) -> Any:
    text = lzma.open(path).read().decode() if path.suffix == ".xz" else path.read_text()
    return text


def _json(cell: Path, name: str) -> Any:
    for p in (cell / f"{name}.xz", cell / name):
        if p.exists():
            return json.loads(_load(p))
    raise FileNotFoundError(cell / name)


def _vehicle(cell: Path) -> list[dict[str, Any]]:
    for p in (cell / "vehicle.jsonl.xz", cell / "vehicle.jsonl"):
        if p.exists():
            return [json.loads(line) for line in _load(p).splitlines() if line.strip().endswith("}")]
    raise FileNotFoundError(cell / "vehicle.jsonl")


def breakdown(cell: Path, window: tuple[int, int], over_ms: float) -> dict[str, Any]:
    t0, t1 = window
    samples = [s for s in _vehicle(cell) if t0 <= s["t"] <= t1 and s.get("sp_stamp")]
    rx = _json(cell, "drone.json")["logs"]["received"]["setpoint"]
    arrived = {seq: (stamp, at) for seq, stamp, at in zip(rx["seq"], rx["stamp_ns"], rx["arrival_ns"], strict=True)}
    drone_id = next(iter(_json(cell, "gcs.json")["drones"]))
    tx = _json(cell, "gcs.json")["drones"][drone_id]["logs"]["sent"]["setpoint"]
    sent = sorted(zip(tx["stamp_ns"], tx["seq"], strict=True))
    try:
        timeline = _json(cell, "loss_timeline.json")
    except FileNotFoundError:
        timeline = []
    ends = [t for t, _, _ in timeline[1:]] + [t1]
    fades = [(t, e) for (t, state, _), e in zip(timeline, ends, strict=True) if state == "bad"]
    episodes = []
    for prev, new in zip(samples, samples[1:], strict=False):
        age = (prev["t"] - prev["sp_stamp"]) / 1e6
        if new["sp_seq"] == prev["sp_seq"] or age <= over_ms or prev["sp_seq"] not in arrived:
            continue
        p_stamp, p_at = arrived[prev["sp_seq"]]
        n_stamp, n_at = arrived[new["sp_seq"]]
        newest = max((seq for stamp, seq in sent if stamp <= n_at), default=new["sp_seq"])
        episodes.append({
            "age_ms": round(age), "prev_age_at_arrival_ms": round((p_at - p_stamp) / 1e6),
            "arrival_gap_ms": round((n_at - p_at) / 1e6), "to_vehicle_ms": round((new["t"] - n_at) / 1e6, 1),
            "new_age_at_arrival_ms": round((n_at - n_stamp) / 1e6), "behind_newest": newest - new["sp_seq"],
            "fades_ms": [round((e - s) / 1e6) for s, e in fades if e > p_at and s < n_at]})
    ages = [(s["t"] - s["sp_stamp"]) / 1e6 for s in samples]
    times = sorted(at for _, at in arrived.values() if t0 <= at <= t1)
    gaps = [(b - a) / 1e6 for a, b in zip(times, times[1:], strict=False)]
    return {"cell": cell.name, "age_max_ms": round(max(ages)) if ages else None,
            "arrival_gaps_over_300_ms": sum(g > 300 for g in gaps),
            "arrival_gaps_over_400_ms": sum(g > 400 for g in gaps), "episodes": episodes}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="a sweep's folder (results.jsonl, cells/)")
    ap.add_argument("cells", nargs="*", help="cell folder names (default: every resilient bursty cell)")
    ap.add_argument("--over", type=float, default=400.0, help="report targets older than this, ms")
    args = ap.parse_args()
    windows = {}
    for line in (args.results / "results.jsonl").read_text().splitlines():
        r = json.loads(line)
        if r.get("cell_dir") and r.get("window_ns"):
            windows[Path(r["cell_dir"]).name] = tuple(r["window_ns"])
    names = args.cells or sorted(n for n in windows if n.startswith("after-resilient~bursty"))
    for name in names:
        print(json.dumps(breakdown(args.results / "cells" / name, windows[name], args.over)))


if __name__ == "__main__":
    main()
