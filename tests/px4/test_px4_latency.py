"""``zenoh-robot lab px4-latency`` (issue #28): the setpoint latency GCS -> PX4 over both backends.

A real run, one short rep per backend: the CLI process runs each simulator (MAVLink over UDP, PX4's Zenoh
protocol behind a router) and the GCS node; the companion is its child. No figure is asserted (they go to
docs/results/px4_zenoh/); what is: the tool runs, and each backend delivered most numbered targets, each
after its publish, with every sample's target (or a newer one) reaching the simulator.
"""
from __future__ import annotations

import gzip
import json
import math
from pathlib import Path

from conftest import python_proc

DURATION_S = 3.0
RATE_HZ = 20.0


def test_px4_latency_measures_both_backends(tmp_path: Path) -> None:
    proc = python_proc("-m", "zenoh_robot.tools.cli.main", "lab", "px4-latency", "--reps", "1",
                       "--duration", str(DURATION_S), "--rate", str(RATE_HZ), "--out", str(tmp_path))
    out, _ = proc.communicate(timeout=150)
    assert proc.returncode == 0, out[-3000:]
    with gzip.open(tmp_path / "latency.jsonl.gz", "rt") as f:
        rows = [json.loads(line) for line in f]
    for backend in ("mavlink", "zenoh"):
        mine = [r for r in rows if r["backend"] == backend]
        assert len(mine) >= DURATION_S * RATE_HZ * 0.7, (backend, len(mine))
        ks = [r["k"] for r in mine]
        assert ks == list(range(ks[0], ks[0] + len(ks))), f"{backend}: samples not consecutive"
        delivered = [r["latency_ms"] for r in mine if r["latency_ms"] is not None]
        assert len(delivered) > len(mine) / 2, f"{backend}: {len(delivered)}/{len(mine)} targets reached PX4"
        assert all(math.isfinite(v) and v > 0 for v in delivered), (backend, sorted(delivered)[:3])
        assert all(r["reached_ms"] is not None and r["reached_ms"] <= (r["latency_ms"] or math.inf)
                   for r in mine), f"{backend}: a sample whose target (or a newer one) never reached PX4"
    table = (tmp_path / "latency.md").read_text()
    assert "| mavlink | 1 |" in table and "| zenoh | 1 |" in table, table
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["mavlink"]["count"] > 0 and summary["zenoh"]["count"] > 0
