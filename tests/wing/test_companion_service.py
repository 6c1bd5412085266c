"""configs/systemd/zenoh-robot-companion.service: systemd accepts it, and its command line is one the
companion takes (a unit that starts a mistyped command restarts forever, every 2 s, silently)."""
from __future__ import annotations

import argparse
import configparser
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import skip_unless_required

from px4_link.connection_url import parse_px4_url

UNIT = Path(__file__).resolve().parents[2] / "configs" / "systemd" / "zenoh-robot-companion.service"


def service() -> configparser.SectionProxy:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str   # type: ignore[assignment,method-assign]   (systemd's keys are case-sensitive)
    unit.read(UNIT)
    return unit["Service"]


@pytest.mark.fast
def test_the_unit_restarts_and_stops_cleanly() -> None:
    s = service()
    assert s["Restart"] == "always" and float(s["RestartSec"]) > 0
    assert "dialout" in s["SupplementaryGroups"]
    assert "KillSignal" not in s   # SIGTERM, which the companion turns into a clean stop and its summary


@pytest.mark.fast
def test_its_command_line_is_one_the_companion_takes() -> None:
    from companion.cli import check_px4, register
    argv = shlex.split(service()["ExecStart"])
    assert argv[0].endswith("/zenoh-robot") and argv[1] == "companion"
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(argv[1:])
    assert parse_px4_url(args.px4).is_serial and args.px4.endswith(":921600")
    problem = check_px4(args.px4)   # the form is right; the device is there only on a drone
    assert problem is None or "no serial device" in problem or "dialout" in problem, problem


def test_systemd_verifies_it(tmp_path: Path) -> None:
    if shutil.which("systemd-analyze") is None:    # `make sysdeps` installs it where it can (root)
        skip_unless_required("no systemd-analyze (Debian's systemd package)")
    # The unit names the drone's venv; here the test's own stands in for it.
    exe = Path(sys.executable).with_name("zenoh-robot")
    text = UNIT.read_text().replace("/home/drone/zenoh-robot/.venv/bin/zenoh-robot", str(exe))
    local = tmp_path / UNIT.name
    local.write_text(text)
    r = subprocess.run(["systemd-analyze", "verify", str(local)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
