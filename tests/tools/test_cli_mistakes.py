"""A user's mistake at start-up is one line on stderr and a non-zero exit, never a traceback (issue #39):
here a second companion with a drone id that is already flying."""
from __future__ import annotations

import os
import secrets
import subprocess
import sys
import time

from conftest import fresh_domain

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_a_second_companion_with_the_same_id_is_one_line_and_exit_1() -> None:
    env = dict(os.environ, ZR_DOMAIN=str(fresh_domain()), PYTHONUNBUFFERED="1")
    drone = f"d{secrets.token_hex(3)}"
    cmd = [sys.executable, "-m", "companion", "--id", drone, "--px4", "sim", "--camera", "none"]
    first = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert first.stdout is not None
        started = False
        end = time.monotonic() + 60.0
        while time.monotonic() < end and not started:
            line = first.stdout.readline()
            if not line:
                break
            started = f"companion {drone}: PX4 at" in line
        assert started, "the first companion did not start"
        second = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
        assert second.returncode == 1, second
        errors = [ln for ln in second.stderr.splitlines() if "zenoh-robot companion:" in ln]
        assert len(errors) == 1 and "already running" in errors[0], second.stderr
        assert "Traceback" not in second.stderr + second.stdout, second.stderr
    finally:
        first.terminate()
        first.wait(timeout=30)
