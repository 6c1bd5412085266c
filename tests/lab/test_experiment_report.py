"""The experiment's report on a small synthetic sweep: one table set per (start, transport), invalid
and broken cells listed instead of read as rates, the sliced viewer's oldest-strip age, command
success joined by loss, and the two summary figures."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from drone_lab.experiment.report import MAX_SLICES, groups, main, markdown_report, oldest_strip_ages

# In-process only, but the two tests that draw the figures are not in the fast tier: matplotlib's first use on
# a machine builds its font cache by running `fc-list` (a process; conftest's fast tier refuses one).
FAST = pytest.mark.fast

MS = 1_000_000


def _stream(delivered: float, gap: float, p99_gap: float, over: int, age99: float, rate: float = 10.0,
            sent: int = 80) -> dict[str, Any]:
    return {"delivered_pct": delivered, "longest_gap_ms": gap, "gap_p99_ms": p99_gap, "gaps_over_500ms": over,
            "age_p99_ms": age99, "age_avg_ms": age99 / 2, "period_avg_ms": 100.0, "rate_hz": rate, "sent": sent,
            "unique": int(sent * delivered / 100)}


def _cell(profile: str, loss: float, transport: str = "default", mode: str = "fec", **extra: Any) -> dict[str, Any]:
    return {"profile": profile if transport == "default" else f"{profile}@{transport}", "transport": transport,
            "loss": loss, "start": "after", "config": {"image_mode": mode},
            "topics": {"setpoint": _stream(100.0, 137.0, 134.0, 0, 38.0),
                       "sensor": _stream(97.5, 60.0, 20.0, 0, 12.0, rate=195.0, sent=1600),
                       "image": _stream(90.0, 300.0, 200.0, 0, 80.0, rate=27.0),
                       "image_whole": _stream(88.0, 300.0, 200.0, 0, 80.0, rate=26.2),
                       "image_strip": _stream(94.0, 300.0, 200.0, 0, 80.0)},
            "bandwidth_kBps": {"gcs": 69.1, "drone": 507.1}, "window_ns": [0, 8000 * MS], **extra}


@pytest.fixture
def sweep() -> list[dict[str, Any]]:
    return [
        _cell("resilient", 50),
        _cell("best_effort", 0, mode="raw"),
        _cell("resilient", 0, transport="unicast"),
        _cell("resilient", 10, invalid="setpoint not sent through the whole window (start-up or exit inside it)"),
        {"profile": "reliable", "loss": 90, "start": "after", "error": "missing records (see x/*.log)", "topics": {}},
    ]


@FAST
def test_one_table_set_per_start_and_transport_with_every_column(sweep: list[dict[str, Any]]) -> None:
    assert list(groups(sweep)) == [("after", "default"), ("after", "unicast")]
    md = markdown_report(sweep)
    assert md.count("### Setpoints and sensors") == 2 and md.count("### Images and bandwidth") == 2
    assert "## Loss applied after set-up, transport unicast" in md
    row = next(line for line in md.splitlines() if line.startswith("| 50% | resilient |"))
    # setpoint delivered, max gap, p99 gap, gaps > 500 ms, p99 age; sensor delivered, p99 age
    # runs, setpoints in window, delivered, max gap, p99 gap, gaps > 500 ms, p99 age; sensor; kB/s each way
    assert row == "| 50% | resilient | 1 | 80 | 100.0% | 137 ms | 134 ms | 0 | 38 ms | 97.5% | 12 ms | 69.1 | 507.1 |"
    img = [line for line in md.splitlines() if line.startswith("| 50% | resilient | fec |")]
    # A FEC frame's strips are exactly as fresh as its frames.
    assert img == ["| 50% | resilient | fec | 26.2 | 88% | 88% | n/a | 69.1 | 507.1 |"]
    assert "| 0% | best_effort | raw |" in md


@FAST
def test_invalid_and_broken_cells_are_listed_not_tabled(sweep: list[dict[str, Any]]) -> None:
    md = markdown_report(sweep)
    assert not any(line.startswith(("| 10% | resilient", "| 90% | reliable")) for line in md.splitlines())
    assert "- 10% resilient: invalid: setpoint not sent through the whole window" in md
    assert "- 90% reliable: error: missing records" in md


@FAST
def test_oldest_strip_age_follows_the_picture_a_sliced_viewer_shows() -> None:
    # Frame 0: strips 0 and 1 at t=0; frame 1: only strip 0 arrives (strip 1 lost), 100 ms later.
    # The picture then still shows frame 0's strip 1: the oldest strip is 100 ms + transit old.
    seq = [0 * MAX_SLICES + 0, 0 * MAX_SLICES + 1, 1 * MAX_SLICES + 0, 2 * MAX_SLICES + 0, 2 * MAX_SLICES + 1]
    stamp = [0, 0, 100 * MS, 200 * MS, 200 * MS]
    arrival = [10 * MS, 10 * MS, 110 * MS, 210 * MS, 210 * MS]
    got = oldest_strip_ages({"seq": seq, "stamp_ns": stamp, "arrival_ns": arrival}, 0, 1000 * MS)
    assert got["samples"] == 5
    assert got["age_max_ms"] == pytest.approx(210.0)    # strip 0 of frame 2 arrives; strip 1 still frame 0's
    assert got["age_p50_ms"] == pytest.approx(10.0)     # ages 10, 10, 110, 210, 10 ms
    # An older frame's strip arriving late does not replace a newer one.
    late = oldest_strip_ages({"seq": [MAX_SLICES, 0], "stamp_ns": [100 * MS, 0], "arrival_ns": [110 * MS, 120 * MS]},
                             0, 1000 * MS)
    assert late["age_max_ms"] == pytest.approx(20.0)    # frame 1's strip 0 (stamp 100) at 120 ms, not 120 ms
    assert oldest_strip_ages({}, 0, 1)["samples"] == 0


def test_report_files_commands_joined_and_sliced_ages_from_the_raw_record(tmp_path: Path,
                                                                          sweep: list[dict[str, Any]]) -> None:
    import matplotlib  # noqa: F401  (a dev dependency: missing is a failure)
    sliced = _cell("resilient", 30, mode="sliced")
    sweep.append(sliced)
    cell_dir = tmp_path / "cells" / "after-resilient-30"
    cell_dir.mkdir(parents=True)
    strips = {"seq": [0, 1, MAX_SLICES], "stamp_ns": [0, 0, 100 * MS], "arrival_ns": [5 * MS, 5 * MS, 105 * MS]}
    record = {"drones": {"uav1": {"logs": {"received": {"image_strip": strips}}}}}
    (cell_dir / "gcs.json").write_text(json.dumps(record))
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in sweep) + '{"cut line\n')
    commands = tmp_path / "commands.jsonl"
    commands.write_text(json.dumps({"loss_pct": 50, "timeout_s": 2, "calls": 100, "answered": 98, "success_rate": 0.98,
                                    "per_command": {"arm": 1, "takeoff": 1, "hold": 0.96, "land": 0.96},
                                    "latency_ms_p50": 52.6, "latency_ms_p90": 388.2, "latency_ms_max": 1230.4,
                                    "attempts_per_call": 3.4, "double_executions": 0,
                                    "executed_but_unanswered": 2}) + "\n")
    assert main([str(tmp_path), "--commands", str(commands)]) == 0
    md = (tmp_path / "results.md").read_text()
    assert ("| 50% | resilient | 1 | 80 | 100.0% | 137 ms | 134 ms | 0 | 38 ms | 97.5% | 12 ms | 69.1 | 507.1 "
            "| 98% of 100 |") in md
    assert "| 0% | best_effort |" in md and "- |" in md.split("| 0% | best_effort |")[1].splitlines()[0]
    assert "## Commands" in md
    # The sliced cell's oldest strip: at the last arrival strip 1 is still frame 0's (105 ms old).
    assert "| 30% | resilient | sliced | 26.2 | 88% | 94% | 105 ms |" in md
    for name in ("summary_after.png", "summary_after_unicast.png", "image_after.png", "results.csv"):
        assert (tmp_path / name).stat().st_size > 0
    assert "Command success per loss: not in this report" in markdown_report(sweep)


@FAST
def test_a_cell_where_the_link_failed_the_stack_is_a_zero_not_a_gap() -> None:
    """Both apps ran through the window but the GCS, never hearing its drone, sent nothing: the thesis's
    "nothing arrives", tabled as 0 % and named, not dropped as a measurement fault to rerun."""
    failed = _cell("reliable", 70, link_failed="setpoint, sensor not sent through the whole window")
    failed["topics"]["setpoint"] = {**_stream(0.0, 8000.0, 8000.0, 1, 0.0, sent=0), "delivered_pct": 0.0}
    md = markdown_report([failed, _cell("resilient", 70)])
    row = next(line for line in md.splitlines() if line.startswith("| 70% | reliable |"))
    assert row.startswith("| 70% | reliable | 1 | 0 | 0.0% |")
    assert "Cells where the link failed the stack" in md and "- 70% reliable: setpoint, sensor not sent" in md


def _flown(profile: str, loss: float, run: int, age: float, share: float = 1.0, failsafes: int = 0,
           **extra: Any) -> dict[str, Any]:
    cmds = {"offboard_start": {"ok": True, "s": 0.9}, "arm": {"ok": True, "s": 0.01}, "land": {"ok": True, "s": 1.1},
            "hold": {"ok": True, "s": 2.2, "probe": True}}
    return _cell(profile, loss, run=run, loss_model=extra.pop("loss_model", "uniform"), flight={
        "mission_ok": failsafes == 0, "offboard_share_window": share, "failsafes": failsafes,
        "vehicle_target": {"age_max_ms": age, "stale_over_500ms": int(age > 500)},
        "path_error_window": {"mean_m": 0.2 + run / 100, "max_m": 0.8}, "commands": cmds}, **extra)


@FAST
def test_runs_give_median_and_range_and_the_flight_table_shows_what_the_vehicle_did() -> None:
    """Issue #29: three runs of a cell are one row (median [min-max]); the flight table says what PX4 did
    (OFFBOARD share, failsafes, the target's age at the vehicle, path error, commands); a bursty row is
    named by its model; an invalid run is listed with its reason, and its figures are in no median."""
    runs = [_flown("resilient", 50, 0, 180.0), _flown("resilient", 50, 1, 220.0), _flown("resilient", 50, 2, 200.0),
            _flown("resilient~bursty", 50, 0, 845.0, share=0.9, failsafes=1, loss_model="bursty",
                   mission_failed="FAILED: offboard: drone left the offboard session"),
            _flown("resilient", 50, 3, 9000.0, invalid="sensor not sent through the whole window")]
    md = markdown_report(runs)
    assert "### Flight" in md
    row = next(line for line in md.splitlines() if line.startswith("| 50% | resilient | 3 | 3/3 |"))
    # OFFBOARD, failsafes, target age max (median [range]), > 500 ms, path error mean, max, commands ok, ...
    assert row.startswith("| 50% | resilient | 3 | 3/3 | 100% | 0 | 200 ms [180 ms-220 ms] | 0 "
                          "| 0.21 m [0.20 m-0.22 m] | 0.80 m | 12/12 | 0.90 | 0.01 | 1.10 | 2.20 | 69.1 | 507.1 |"), row
    bursty = next(line for line in md.splitlines() if line.startswith("| 50% bursty | resilient~bursty | 1 | 0/1 |"))
    assert "| 90% | 1 | 845 ms | 1 |" in bursty
    assert "- 50% resilient run 3: invalid: sensor not sent" in md
    assert "- 50% resilient~bursty run 0: FAILED: offboard: drone left" in md
    # One that failed after its window (the land's answer lost) is listed too, with the mission's reason.
    late = _flown("resilient", 90, 0, 300.0)
    late["flight"]["mission_ok"], late["flight"]["mission_result"] = False, "FAILED: land: ServiceTimeout"
    assert "- 90% resilient run 0: FAILED: land: ServiceTimeout" in markdown_report([late])
    assert "9.0 s" not in md    # the invalid run's age is in no figure
    streams = next(line for line in md.splitlines() if line.startswith("| 50% | resilient | 3 | 80 |"))
    assert streams.endswith("| 69.1 | 507.1 |")


@FAST
def test_a_flight_that_failed_before_its_window_counts_as_a_failed_flight() -> None:
    """From start-up a session or a command may not cross the loss: the mission fails before the window
    and no setpoint is sent in it. That is a failed flight (0/1 in the table, listed with its reason),
    not a window to leave out."""
    failed = _flown("resilient", 50, 0, float("nan"), share=float("nan"), start="startup",
                    transport="unicast", mission_failed="FAILED: drone connected: no state from the drone")
    failed["flight"]["mission_ok"] = False
    failed["topics"]["setpoint"] = {"sent": 0, "unique": 0}
    md = markdown_report([failed])
    assert any(line.startswith("| 50% | resilient@unicast | 1 | 0/1 |") for line in md.splitlines()), md
    assert "- 50% resilient@unicast run 0: FAILED: drone connected: no state" in md
    assert "Cells left out" not in md


def test_report_only_regenerates_from_the_kept_raw_results(tmp_path: Path) -> None:
    """One command redraws every table from results.jsonl, the invalid lines included in the listing."""
    from zenoh_robot.tools.cli.main import main as cli

    lines = [_flown("resilient", 70, i, 150.0 + i) for i in range(3)]
    for i, line in enumerate(lines):     # runs differ in their stream figures too, as real runs do
        line["topics"]["setpoint"]["longest_gap_ms"] = 200.0 + i
    lines.append(_flown("reliable", 70, 0, 4000.0, invalid="setpoint not sent through the whole window"))
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert cli(["experiment", "--report-only", str(tmp_path)]) == 0
    md = (tmp_path / "results.md").read_text()
    assert "| 70% | resilient | 3 | 3/3 | 100% | 0 | 151 ms [150 ms-152 ms] |" in md
    assert "- 70% reliable run 0: invalid: setpoint not sent" in md
    csv_lines = (tmp_path / "results.csv").read_text().splitlines()
    assert "vehicle_target_age_max_ms" in csv_lines[0] and len(csv_lines) == 1 + 4 * 6
    # the figures draw one point per loss level, the runs' median (three runs of a cell used to crash them)
    assert (tmp_path / "summary_after.png").stat().st_size > 0 and (tmp_path / "setpoint_after.png").exists()
