"""A smoke run of the benchmark: every figure it reports is there and sane (no timing targets)."""
from __future__ import annotations

import math

from zenoh_robot.tools.bench.report import markdown
from zenoh_robot.tools.bench.runner import Cell, run_cell


def test_small_and_image_cells_produce_complete_figures() -> None:
    lat = run_cell(Cell("setpoint", "latency", 200, 100))
    thr = run_cell(Cell("jpeg", "throughput", 0, 100))
    for r in (lat, thr):
        for f in (r.framework, r.raw):
            assert not f.error, f.error
            assert f.sent == r.cell.count and f.received == r.cell.count   # reliable: nothing lost
            assert f.cpu_us_per_msg_sub > 0 and f.cpu_us_per_msg_pub > 0
    assert 0 < lat.framework.p50_ms <= lat.framework.p99_ms < 1000
    assert 0 < lat.raw.p50_ms <= lat.raw.p99_ms < 1000
    assert math.isfinite(lat.ratios["p50"]) and math.isfinite(thr.ratios["throughput"])
    assert thr.framework.msgs_per_s > 0 and thr.framework.mb_per_s > 0 and thr.payload_bytes > 10_000
    md = markdown([lat, thr], None)
    assert "setpoint" in md and "jpeg" in md and md.count("\n") == 3
