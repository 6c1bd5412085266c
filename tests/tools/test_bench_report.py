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
