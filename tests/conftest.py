"""Shared fixtures: unique namespaces so parallel or repeated tests never hear each other."""
from __future__ import annotations

import os
import secrets
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def ns() -> str:
    """A namespace no other test (or earlier run) uses."""
    return f"t{secrets.token_hex(4)}"


def wait_for(predicate: Callable[[], bool], timeout: float = 5.0, interval: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()


def python_proc(*args: str, env: dict[str, str] | None = None, **kw) -> subprocess.Popen:
    """A real child process running this venv's Python, output captured as text."""
    full_env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
    return subprocess.Popen([sys.executable, *args], cwd=ROOT, env=full_env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, **kw)
