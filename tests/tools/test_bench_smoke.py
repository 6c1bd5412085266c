"""A smoke run of the benchmark: every figure it reports is there and sane (no timing targets)."""
from __future__ import annotations

import math

from zenoh_robot.tools.bench.report import markdown
from zenoh_robot.tools.bench.runner import Cell, run_cell, spread


def test_small_and_image_cells_produce_complete_figures() -> None:
    lat = run_cell(Cell("setpoint", "latency", 200, 100))
    thr = run_cell(Cell("jpeg", "throughput", 0, 100))
    for r in (lat, thr):
        for f in (r.framework, r.raw):
            assert not f.error, f.error
            assert f.sent == r.cell.count and f.received == r.cell.count   # reliable: nothing lost
            assert f.cpu_us_per_msg_sub > 0 and f.cpu_us_per_msg_pub > 0
            # The subscriber's CPU before its first sample (the publisher's discovery) is reported apart.
            assert 0 < f.cpu_ms_setup_sub < 60_000
    assert "(set-up " in markdown([lat], None)
    assert 0 < lat.framework.p50_ms <= lat.framework.p99_ms < 1000
    assert 0 < lat.raw.p50_ms <= lat.raw.p99_ms < 1000
    assert math.isfinite(lat.ratios["p50"]) and math.isfinite(thr.ratios["throughput"])
    assert thr.framework.msgs_per_s > 0 and thr.framework.mb_per_s > 0 and thr.payload_bytes > 10_000
    md = markdown([lat, thr], None)
    assert "setpoint" in md and "jpeg" in md and md.count("\n") == 3


def test_repetitions_alternate_and_report_median_spread_and_load() -> None:
    """Issue #30: figures a shared machine can be trusted with: A/B repetitions, their median and
    spread, the load average beside them; the channel receive path measured like the default."""
    r = run_cell(Cell("setpoint", "throughput", 0, 2000), reps=3, receive="channel")
    assert r.receive == "channel" and len(r.runs) == 3
    assert not r.framework.error and not r.raw.error
    assert r.framework.received == r.raw.received == 2000           # the worst repetition: nothing lost
    per_run = [run["throughput"] for run in r.runs]
    assert all(math.isfinite(x) and x > 0 for x in per_run)
    assert r.ratios["throughput"] == sorted(per_run)[1]              # the median of the three
    low, high = spread(r, "throughput")
    assert low == min(per_run) and high == max(per_run)
    assert all(run["load1"] >= 0 for run in r.runs) and r.load[0] <= r.load[1]
    row = markdown([r], None).splitlines()[-1]
    assert f"({low:.2f}-{high:.2f})" in row and f"{r.load[0]:.1f}-{r.load[1]:.1f}" in row and "| 3 |" in row


def test_ros2_bench_alternates_modes_and_reports_median_spread_and_load(tmp_path) -> None:
    """The ROS 2 wire beside the envelope, zenoh-ros2-sdk and raw zenoh-python (issues #27, #30, #43): every
    mode in each repetition, ratios to that repetition's raw run, each side's CPU per message, the codec
    figures with rosbags' beside the fast path."""
    import json

    from zenoh_robot.tools.bench.ros2 import codec_figures, end_to_end, write_json
    from zenoh_robot.tools.bench.ros2 import markdown as ros2_markdown

    rows = end_to_end(reps=2, cells=(("geometry_msgs/msg/PoseStamped", "throughput", 0.0, 300),))
    assert [r["mode"] for r in rows] == ["ros2", "envelope", "sdk", "raw"]
    for r in rows:
        assert not r["error"], r["error"]
        assert r["reps"] == 2 and len(r["runs"]) == 2 and r["received"] == r["sent"] == 300
        assert r["ratio_low"] <= r["ratio"] <= r["ratio_high"] and r["load"][0] <= r["load"][1]
        assert r["cpu_us_sub"] > 0 and r["cpu_us_pub"] > 0 and math.isfinite(r["cpu_sub_ratio"])
    assert rows[3]["ratio"] == rows[3]["cpu_sub_ratio"] == 1.0
    codec = codec_figures(budget_s=0.01)
    assert {"rosbags_encode_us", "rosbags_decode_us", "cdr_encode_us"} <= set(codec[0])
    md = ros2_markdown(codec, rows)
    assert "PoseStamped throughput | ros2 | 300/300" in md and "PoseStamped throughput | sdk | 300/300" in md
    assert "| 2 |" in md
    write_json(tmp_path / "ros2.json", codec, rows)
    assert json.loads((tmp_path / "ros2.json").read_text())["end_to_end"][0]["runs"][1]["received"] == 300


def test_express_cells_run_both_sides_express_and_say_so() -> None:
    """`zenoh-robot bench --express`: both sides publish express; every figure still there, and the
    table says the cells were express (issue #30: express measured, not assumed)."""
    r = run_cell(Cell("setpoint", "throughput", 0, 500), express=True)
    assert r.express and not r.framework.error and not r.raw.error
    assert r.framework.received == r.raw.received == 500
    md = markdown([r], None)
    assert md.splitlines()[-1] == "Both sides published with Zenoh's express (each sample sent at once, no batching)."
    assert "express" not in markdown([run_cell(Cell("setpoint", "latency", 200, 50))], None)


def test_ros2_bench_without_zenoh_ros2_sdk_says_so_in_the_sdk_row(monkeypatch) -> None:
    """Without the peer installed its row says why and how to get it, and the other modes still run."""
    from zenoh_robot.tools.bench import ros2, ros2_sdk

    monkeypatch.setattr(ros2_sdk, "available", lambda: False)
    monkeypatch.setattr(ros2, "MODES", ("sdk", "raw"))
    rows = ros2.end_to_end(reps=1, cells=(("geometry_msgs/msg/PoseStamped", "throughput", 0.0, 100),))
    sdk, raw = rows
    assert sdk["error"] == ros2_sdk.MISSING and "pip install 'zenoh-robot[bench]'" in sdk["error"]
    assert not raw["error"] and raw["received"] == 100
    assert f"| PoseStamped throughput | sdk | error: {ros2_sdk.MISSING}" in ros2.markdown([], rows)
