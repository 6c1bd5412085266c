"""``companion --config-file`` (issue #38): one YAML file holds a drone's settings, each key a flag's long
name; a flag on the command line wins wherever it stands; a mistake in the file is one line, exit 2."""
from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import cli
from conftest import fresh_domain

from zenoh_robot.tools.cli.config_file import ConfigFileError, apply_config_file
from zenoh_robot.tools.cli.main import build_parser

SETTINGS = """\
id: uav7
px4: sim
sensor-rate: 50          # a flag's long name, dashes ...
camera_rate: 5           # ... or underscores
profile: reliable
allow-force-disarm: false
duration: 2
"""


def _parsed(tmp_path: Path, text: str, *flags: str):
    path = tmp_path / "drone.yaml"
    path.write_text(text)
    argv = ["companion", *flags[:1], "--config-file", str(path), *flags[1:]]
    parser = build_parser()
    return apply_config_file(parser, parser.parse_args(argv), argv)


@pytest.mark.fast
def test_the_files_settings_are_the_defaults_and_the_command_line_wins(tmp_path: Path) -> None:
    args = _parsed(tmp_path, SETTINGS)
    assert (args.id, args.px4, args.sensor_rate, args.camera_rate, args.profile) == ("uav7", "sim", 50.0, 5, "reliable")
    assert args.allow_force_disarm is False and args.duration == 2.0
    # Before or after the file on the command line, a flag wins.
    args = _parsed(tmp_path, SETTINGS, "--id=uav9", "--sensor-rate", "100")
    assert (args.id, args.sensor_rate, args.profile) == ("uav9", 100.0, "reliable")


@pytest.mark.fast
@pytest.mark.parametrize(("text", "says"), [
    ("idd: uav1\n", "no setting 'idd'; the flags' long names are:"),
    ("profile: fastest\n", "profile: 'fastest' is not one of"),
    ("sensor-rate: fast\n", "sensor-rate: --sensor-rate does not take 'fast'"),
    ("allow-force-disarm: yes please\n", "is a switch, give true or false"),
    ("id: [uav1, uav2]\n", "--id takes one value"),
    ("- id\n- uav1\n", "a mapping of flag names to values, got list"),
    ("id: [uav1\n", "not YAML"),
])
def test_a_mistake_in_the_file_names_the_key(tmp_path: Path, text: str, says: str) -> None:
    with pytest.raises(ConfigFileError, match=None) as err:
        _parsed(tmp_path, text)
    assert says in str(err.value) and str(tmp_path / "drone.yaml") in str(err.value), str(err.value)


def test_the_companion_runs_from_its_file_and_a_mistake_is_one_line(tmp_path: Path) -> None:
    good = tmp_path / "uav7.yaml"
    good.write_text(SETTINGS + f"domain: {fresh_domain()}\n")
    run = cli("companion", "--config-file", str(good), merged=True, timeout=60)
    assert run.returncode == 0, run.stdout[-2000:]
    assert "companion uav7: PX4 at" in run.stdout, run.stdout[-2000:]
    bad = tmp_path / "bad.yaml"
    bad.write_text("px44: sim\n")
    run = cli("companion", "--config-file", str(bad))
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines() == [run.stderr.strip()] and "no setting 'px44'" in run.stderr
    missing = cli("companion", "--config-file", str(tmp_path / "nope.yaml"))
    assert missing.returncode == 2 and "No such file" in missing.stderr and "Traceback" not in missing.stderr


@pytest.mark.fast
def test_the_shipped_example_is_one_the_companion_takes() -> None:
    example = Path(__file__).resolve().parents[2] / "configs" / "companion" / "uav1.yaml"
    argv = ["companion", "--config-file", str(example)]
    parser = build_parser()
    args = apply_config_file(parser, parser.parse_args(argv), argv)
    assert (args.id, args.px4, args.profile, args.iface, args.camera) == \
        ("uav1", "/dev/serial0:921600", "resilient", "wlan0", "none")
