"""Shared fixtures: unique namespaces so parallel or repeated tests never hear each other."""
from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def ns() -> str:
    """A namespace no other test (or earlier run) uses."""
    return f"t{secrets.token_hex(4)}"


def skip_unless_required(reason: str) -> None:
    """Skip, saying why; but where CI asks for everything (ZR_REQUIRE_NETNS=1, set by .ci/run,
    whose `make test` installs the system tools), a missing capability fails the test."""
    if os.environ.get("ZR_REQUIRE_NETNS") == "1":
        pytest.fail(f"ZR_REQUIRE_NETNS=1 but {reason}")
    pytest.skip(reason)


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


def free_port() -> int:
    """A port free for both TCP and UDP on 127.0.0.1."""
    import socket
    with socket.socket() as t, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        t.bind(("127.0.0.1", 0))
        port = t.getsockname()[1]
        u.bind(("127.0.0.1", port))
        return port


def linked_configs():
    """Session configs for a listener and a connector on loopback, TCP + UDP, no scouting.

    Tests that are not about discovery use these, so they never wait on multicast scouting
    (which a busy machine can delay) nor meet other tests' sessions.
    """
    from zenoh_robot import SessionConfig
    endpoints = [f"tcp/127.0.0.1:{free_port()}", f"udp/127.0.0.1:{free_port()}"]
    listen = SessionConfig(listen=endpoints, multicast_scouting=False, shared_memory=False)
    connect = SessionConfig(listen=[], connect=endpoints, multicast_scouting=False, shared_memory=False)
    return listen, connect


@contextmanager
def linked_nodes(ns: str, links: int = 2):
    """(talker, listener): two Nodes in namespace ``ns`` whose sessions hold ``links`` links."""
    from zenoh_robot import Node
    listen, connect = linked_configs()
    with Node("listener", namespace=ns, config=listen) as b, Node("talker", namespace=ns, config=connect) as a:
        peer = b.session.zid()
        assert wait_for(lambda: len([l for l in a.session.info.links() if l.zid == peer]) >= links, 10.0), \
            "the two sessions never linked"
        yield a, b


def stop_process(proc: subprocess.Popen, timeout: float = 15.0) -> str:
    """Ctrl-C a process as a user would (it stops cleanly and prints its summary), kill it if it
    hangs; returns what it printed."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""


def wait_ready(proc: subprocess.Popen, max_lines: int = 50) -> bool:
    """Read a helper process's stdout up to its READY line. Zenoh 1.10 logs its own errors to stdout
    (e.g. a transient "Unknown wire expr" while sessions meet): those lines are not the protocol."""
    assert proc.stdout is not None
    for _ in range(max_lines):
        line = proc.stdout.readline()
        if not line:
            return False
        if line.strip() == "READY":
            return True
    return False


def last_json(out: str) -> dict:
    """The last JSON object a helper process printed (its summary), skipping Zenoh's log lines."""
    import json
    for line in reversed(out.strip().splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise AssertionError(f"no JSON summary in: {out[-2000:]!r}")
