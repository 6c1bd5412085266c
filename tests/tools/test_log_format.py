"""One log format for every program (issue #39): the CLI's (companion, GCS, tools) and both simulators'
command lines log ``<date> <time>,<ms> <LEVEL> <logger>: <message>``, so a log collector, or a reader
of a launch's interleaved output, parses them all alike."""
from __future__ import annotations

import re

import pytest
from cli_helpers import cli

from px4_link.sim import cli as mavlink_sim_cli
from px4_zenoh.sim import cli as zenoh_sim_cli
from zenoh_robot.tools.cli import main as zr_cli

LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} (DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.\-]+: \S")


def test_every_program_formats_its_log_alike() -> None:
    assert mavlink_sim_cli.LOG_FORMAT == zenoh_sim_cli.LOG_FORMAT == zr_cli.LOG_FORMAT


@pytest.mark.usefixtures("own_domain")
def test_the_companion_and_the_simulator_log_lines_parse_as_one_format() -> None:
    run = cli("companion", "--id", "uavlog", "--px4", "sim", "--camera", "none", "--duration", "2",
              "--listen", "tcp/127.0.0.1:0", timeout=90)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert lines and all(LINE.match(ln) for ln in lines), [ln for ln in lines if not LINE.match(ln)][:5]
