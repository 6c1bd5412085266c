"""The bench's terminal table reads in an 80-column terminal: one line a cell, the ratios kept; the full
table (every figure) where there is room."""
from __future__ import annotations

import io

import pytest
from rich.console import Console

from zenoh_robot.tools.bench.report import FULL_WIDTH, table
from zenoh_robot.tools.bench.runner import Cell, CellResult, Figures

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def _results() -> list[CellResult]:
    lat = CellResult(Cell("setpoint", "latency", 1000, 3000),
                     Figures(3000, 3000, 0.158, 0.25, cpu_us_per_msg_sub=112.0),
                     Figures(3000, 3000, 0.151, 0.25, cpu_us_per_msg_sub=101.0), 45,
                     ratios={"p50": 1.08, "cpu_sub": 1.11},
                     runs=[{"p50": 0.99, "cpu_sub": 1.0}, {"p50": 1.08, "cpu_sub": 1.11},
                           {"p50": 1.12, "cpu_sub": 1.2}],
                     load=(0.4, 0.5))
    thr = CellResult(Cell("sensor", "throughput", 0, 30000),
                     Figures(30000, 30000, msgs_per_s=104418.0, mb_per_s=13.4, cpu_us_per_msg_sub=10.0),
                     Figures(30000, 30000, msgs_per_s=157688.0, mb_per_s=20.2, cpu_us_per_msg_sub=7.0), 128,
                     ratios={"throughput": 0.79, "cpu_sub": 1.18},
                     runs=[{"throughput": 0.62}, {"throughput": 0.79}, {"throughput": 0.88}], load=(0.2, 0.3))
    return [lat, thr]


def _render(width: int) -> list[str]:
    out = io.StringIO()
    Console(file=out, width=width, force_terminal=False).print(table(_results(), width))
    return out.getvalue().splitlines()


@pytest.mark.parametrize("width", [80, 120])
def test_a_narrow_terminal_gets_one_line_a_cell_that_fits(width: int) -> None:
    lines = _render(width)
    assert max(len(line) for line in lines) <= width
    sp = [line for line in lines if "setpoint 45 B 1000 Hz" in line]
    assert len(sp) == 1 and "1.08 (0.99-1.12)" in sp[0] and "1.11x" in sp[0] and "ok" in sp[0]
    se = [line for line in lines if "sensor 128 B max" in line]
    assert len(se) == 1 and "0.79 (0.62-0.88)" in se[0] and "1.18x" in se[0] and "under 0.9x" in se[0]


def test_a_wide_terminal_gets_every_figure() -> None:
    text = "\n".join(_render(FULL_WIDTH + 20))
    assert "p50 0.158 / 0.151 ms" in text and "104418 / 157688 msg/s" in text and "112 / 101" in text


def _ros2_rows() -> tuple[list[dict[str, object]], list[dict[str, object]]]:
    codec = [{"type": "geometry_msgs/msg/PoseStamped", "cdr_bytes": 84, "cdr_encode_us": 2.5, "cdr_decode_us": 2.6,
              "rosbags_encode_us": 8.1, "rosbags_decode_us": 10.2, "msgpack_encode_us": 2.7, "msgpack_decode_us": 2.0}]
    e2e = [{"type": "sensor_msgs/msg/CompressedImage", "kind": "latency", "rate_hz": 30.0, "mode": mode, "reps": 5,
            "received": 150, "sent": 150, "ratio": ratio, "ratio_low": ratio - 0.1, "ratio_high": ratio + 0.1,
            "cpu_sub_ratio": cpu, "error": ""}
           for mode, ratio, cpu in (("ros2", 1.07, 1.19), ("sdk", 1.25, 1.05), ("raw", 1.0, 1.0))]
    e2e.append({"type": "geometry_msgs/msg/PoseStamped", "kind": "throughput", "rate_hz": 0.0, "mode": "sdk",
                "reps": 5, "error": "zenoh-ros2-sdk is not installed: pip install 'zenoh-robot[bench]'"})
    return codec, e2e


@pytest.mark.parametrize("width", [80, 120])
def test_bench_ros2_in_a_narrow_terminal_gets_one_line_a_cell_and_mode(width: int) -> None:
    from zenoh_robot.tools.bench.report import ros2_tables

    out = io.StringIO()
    console = Console(file=out, width=width, force_terminal=False)
    for t in ros2_tables(*_ros2_rows()):
        console.print(t)
    lines = out.getvalue().splitlines()
    assert max(len(line) for line in lines) <= width
    sdk = [line for line in lines if "CompressedImage 30 Hz" in line and " sdk " in line]
    assert len(sdk) == 1 and "1.25 (1.15-1.35)" in sdk[0] and "1.05x" in sdk[0] and "150/150" in sdk[0]
    assert any("PoseStamped max" in line and "error (below)" in line for line in lines)
    assert "sdk: zenoh-ros2-sdk is not installed: pip install 'zenoh-robot[bench]'" in " ".join(
        line.strip() for line in lines)
    assert any("PoseStamped" in line and "2.5 / 2.6" in line and "8.1 / 10.2" in line for line in lines)
