"""Per-run flight table of this folder (and of any sweep folder given): OFFBOARD share, HOLDs, link losses,
the target age at the vehicle, bandwidth; from results.jsonl and the cells' raw records.

    python docs/results/lossy/unicast-2026-11-25/per_run.py [DIR] > per_run.md

A link loss is a silence of over 1 s in either direction inside the loss window: the drone hearing no
setpoint (10 Hz, copies every few 10 ms) or the GCS hearing no state (5 Hz, copies), or a peer's
liveliness lost in the window (the apps' logs). Under bursty loss a silence up to the longest fade
(95 % drop) is the channel's, not the link's."""
import json
import lzma
import sys
from datetime import UTC, datetime
from pathlib import Path

DIR = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent


def _load(p: Path) -> dict:
    if p.exists():
        return json.loads(p.read_text())
    return json.loads(lzma.open(f"{p}.xz", "rt").read())


def _text(p: Path) -> str:
    if p.exists():
        return p.read_text()
    x = Path(f"{p}.xz")
    return lzma.open(x, "rt").read() if x.exists() else ""


def _silences(arrivals: list[int], t0: int, t1: int) -> list[tuple[float, float]]:
    ts = sorted(a for a in arrivals if t0 <= a <= t1)
    edges = [t0, *ts, t1]
    return [((a - t0) / 1e9, (b - a) / 1e9) for a, b in zip(edges, edges[1:], strict=False) if b - a > 1e9]


def _stamp(line: str) -> int:
    """A log line's time (the apps log UTC as 'YYYY-MM-DD HH:MM:SS,mmm'), ns; 0 if it has none."""
    try:
        t = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").replace(tzinfo=UTC)
    except ValueError:
        return 0
    return int(t.timestamp() * 1e9)


rows = []
for line in (DIR / "results.jsonl").read_text().splitlines():
    r = json.loads(line)
    if r.get("invalid"):
        rows.append(f"| {r['profile']} | {r['loss']:g} % | {r['run']} | invalid: {r.get('invalid')} ||||||||")
        continue
    cell = DIR / "cells" / r["cell_dir"]
    t0, t1 = r["window_ns"]
    drone, gcs = _load(cell / "drone.json"), _load(cell / "gcs.json")["drones"]["uav1"]
    down = _silences(drone["logs"]["received"]["setpoint"]["arrival_ns"], t0, t1)
    up = _silences(gcs["logs"]["received"]["state"]["arrival_ns"], t0, t1)
    logs = _text(cell / "drone.log") + _text(cell / "gcs.log")
    gone = sum(("liveliness lost" in ln or " gone (" in ln) and t0 <= _stamp(ln) <= t1 for ln in logs.splitlines())
    f, v = r["flight"], r["flight"]["vehicle_target"]
    losses = "; ".join([*(f"to drone +{s:.1f} s: {d:.1f} s" for s, d in down),
                        *(f"to GCS +{s:.1f} s: {d:.1f} s" for s, d in up)]) or "none"
    fade = r.get("channel", {}).get("bad_longest_s")
    rows.append(f"| {r['profile']} | {r['loss']:g} % {r.get('loss_model', 'uniform')} | {r['run']} | "
                f"{f'{fade:.1f} s' if fade else '-'} | "
                f"{'ok' if f['mission_ok'] else 'FAILED'} | {f['offboard_share_window']:.0%} | {f['holds']} | "
                f"{losses}{f' (liveliness lost x{gone})' if gone else ''} | {v['age_max_ms']:.0f} ms | "
                f"{v['stale_over_500ms']} | {r['bandwidth_kBps']['gcs']:.1f} | {r['bandwidth_kBps']['drone']:.1f} |")
print("| cell | loss | run | longest fade | mission | OFFBOARD (window) | HOLDs | "
      "link losses (silence > 1 s in the window) | target age at vehicle max | target > 500 ms | "
      "GCS -> drone kB/s | drone -> GCS kB/s |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
print("\n".join(sorted(rows)))
