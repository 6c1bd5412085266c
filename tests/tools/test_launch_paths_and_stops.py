"""A launch file anywhere finds its neighbours, and its programs stop without a traceback (issue #39).

- Relative paths in a launch file are the file's own: one written outside configs/launch/ and started
  from another directory still hands its processes the files beside it.
- A stop (SIGINT from a launch, Ctrl-C) that comes while a program is still importing, before any handler
  of its own, ends it quietly with exit 130: Python would print a KeyboardInterrupt traceback.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from cli_helpers import CLI
from conftest import ROOT

from zenoh_robot.tools.launch import load_launch

READ = "import sys; print('read:', open(sys.argv[1]).read().strip(), '|', sys.argv[2].partition('=')[2])"


def test_relative_paths_in_a_launch_file_are_the_launch_files(tmp_path):
    here = tmp_path / "mine"
    here.mkdir()
    (here / "data.txt").write_text("beside the launch file\n")
    (here / "client.json5").write_text("{}\n")
    launch = here / "fly.yaml"
    launch.write_text(textwrap.dedent(f"""\
        processes:
          - name: reader
            cmd: ["{sys.executable}", "-c", "{READ}", data.txt, --zenoh=client.json5]
            args: [uav1, not_here.txt, -v]
        """))
    spec, = load_launch(launch).processes
    assert spec.argv[3:] == [str(here / "data.txt"), f"--zenoh={here / 'client.json5'}", "uav1", "not_here.txt", "-v"]
    # run from elsewhere (the repository), as `zenoh-robot launch /path/to/fly.yaml`
    r = subprocess.run([*CLI, "launch", str(launch)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"read: beside the launch file | {here / 'client.json5'}" in r.stdout, r.stdout


def test_a_path_in_the_working_directory_is_left_to_the_process(tmp_path, monkeypatch):
    here, there = tmp_path / "launch", tmp_path / "work"
    here.mkdir()
    there.mkdir()
    for d in (here, there):
        (d / "mission.yaml").write_text("{}\n")
    launch = here / "x.yaml"
    launch.write_text('processes:\n  - {name: p, cmd: [prog, mission.yaml]}\n')
    monkeypatch.chdir(there)
    assert load_launch(launch).processes[0].argv == ["prog", "mission.yaml"]


# The module a program's imports pass through on the way to its own code (-X importtime names each as
# it finishes): a SIGINT sent then lands while the program is still importing.
@pytest.mark.parametrize("argv, imported", [
    (["-m", "gcs", "--drones", "uav1", "--no-dashboard"], "zenoh"),
    (["-m", "companion", "--id", "uav1", "--px4", "sim"], "zenoh"),
    (["-m", "px4_link.sim", "--port", "0"], "pymavlink"),
    (["-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())", "topic", "list"], "zenoh"),
], ids=["gcs", "companion", "sim", "zenoh-robot"])
def test_a_stop_while_a_program_is_still_importing_prints_no_traceback(argv, imported, own_domain):
    from zenoh_robot.tools.launch import _guarded

    started = _guarded([sys.executable, *argv])   # as a launch starts it
    proc = subprocess.Popen([started[0], "-X", "importtime", *started[1:]], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            # a test run in the background hands its children SIGINT ignored
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if line.rsplit("|", 1)[-1].strip() == imported:
                proc.send_signal(signal.SIGINT)
                break
        _out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    assert proc.returncode in (0, 130), (proc.returncode, err[-3000:])


def test_the_launch_runs_python_modules_and_zenoh_robot_guarded():
    from zenoh_robot.tools.launch import _ZENOH_ROBOT, _guarded

    assert _guarded([sys.executable, "-m", "gcs", "--x"])[:2] == [sys.executable, "-c"]
    assert _guarded([sys.executable, "-m", "gcs", "--x"])[3:] == ["gcs", "--x"]
    assert _guarded([*_ZENOH_ROBOT, "topic"])[-1] == "topic" and "KeyboardInterrupt" in _guarded(_ZENOH_ROBOT)[2]
    assert _guarded(["prog", "a"]) == ["prog", "a"]
    assert Path(sys.executable).exists()


def test_sigterm_stops_the_gcs_as_ctrl_c_does(own_domain):
    from conftest import Lines, kill_process, python_proc

    proc = python_proc("-m", "gcs", "--drones", "uav1", "--no-dashboard")
    try:
        out = Lines(proc)
        assert out.wait_for("uav1: waiting for state", 60.0), out.text()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    finally:
        kill_process(proc)
    assert proc.returncode == 130, out.text()[-3000:]
    assert out.wait_for("gcs: interrupted", 10.0) and "Traceback" not in out.text(), out.text()[-3000:]
