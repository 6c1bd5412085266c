"""configs/launch/secure.yaml as an operator runs it: router, companion and GCS mission, all --secure."""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from conftest import ROOT, free_port, python_proc

import zenoh_robot.tools.keys as keys
from zenoh_robot.tools.launch import load_launch  # noqa: E402

LAUNCH = ROOT / "configs" / "launch" / "secure.yaml"


def _keys(d: Path) -> None:
    keys.init_ca(d)
    keys.issue(d, "router", "router")
    keys.issue(d, "gcs", "gcs", drones=["uav1"])
    keys.issue(d, "uav1", "drone")


def test_every_process_of_the_secure_launch_file_is_secure(tmp_path: Path) -> None:
    desc = load_launch(LAUNCH, {"keys": str(tmp_path), "port": "7999", "domain": "3"})
    assert [p.name for p in desc.processes] == ["router", "companion", "gcs"]
    for p in desc.processes:
        argv = " ".join(p.argv)
        assert f"--secure {tmp_path}" in argv and "--domain 3" in argv, argv
        assert "tls/127.0.0.1:7999" in argv, argv


def test_secure_launch_file_flies_a_mission(tmp_path: Path) -> None:
    d = tmp_path / "keys"
    _keys(d)
    proc = python_proc("-m", "zenoh_robot.tools.cli.main", "launch", str(LAUNCH), f"keys:={d}",
                       f"port:={free_port()}", "duration:=2")
    try:
        out, _ = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f"launch did not end: {out[-3000:]}")
    assert "mission ok" in out, out[-3000:]
    assert "secure (router" in out, out[-3000:]          # the router's first line: it really is the secure one
    assert proc.returncode == 0, out[-3000:]
    assert "Traceback" not in out, out
