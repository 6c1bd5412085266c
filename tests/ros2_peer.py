"""Shared by the ROS 2 interop tests: the zenoh-ros2-sdk child process, its .msg files, a router.

The peer is an independent implementation of rmw_zenoh's wire format (PyPI zenoh-ros2-sdk), run in its
own process: it prints JSON lines on stdout (``Peer.find``) and takes commands on stdin (``Peer.send``).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import zenoh
from conftest import free_port

from zenoh_robot.ros2 import dependencies, msg_definition

ROOT = Path(__file__).resolve().parents[1]

# The start of every peer script: the SDK reads .msg files from argv[1] (it would fetch them from git),
# argv[2] and argv[3] are the router's port and the ROS domain; ``out`` prints one JSON line at a time
# (subscribers call it from their own threads), which ``Peer.find`` reads.
PEER_PRELUDE = r"""
import json, sys, threading, time
import zenoh_ros2_sdk.message_registry as registry
registry._registry = registry.MessageRegistry(sys.argv[1])
port, domain = int(sys.argv[2]), int(sys.argv[3])
common = dict(domain_id=domain, router_ip="127.0.0.1", router_port=port, namespace="/sdk")

_out_lock = threading.Lock()

def out(**kw):   # subscribers call it from their own threads: one whole line at a time
    with _out_lock:
        sys.stdout.write(json.dumps(kw) + "\n")
        sys.stdout.flush()
"""


class Peer:
    """The zenoh-ros2-sdk child: commands on stdin, JSON lines on stdout."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.lines: list[dict[str, Any]] = []
        self.raw: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        # The peer prints from its subscribers' threads: two objects may share a line ("{...}{...}").
        assert self.proc.stdout is not None
        decoder = json.JSONDecoder()
        for line in self.proc.stdout:
            self.raw.append(line)
            at = line.find("{")
            while at >= 0:
                try:
                    obj, end = decoder.raw_decode(line, at)
                except ValueError:
                    break
                if isinstance(obj, dict):
                    self.lines.append(obj)
                at = line.find("{", end)

    def send(self, cmd: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(cmd + "\n")
        self.proc.stdin.flush()

    def find(self, key: str, value: Any = None) -> list[dict[str, Any]]:
        return [d for d in list(self.lines) if key in d and (value is None or d[key] == value)]

    def values(self, key: str) -> list[Any]:
        return [d[key] for d in self.find(key)]


def write_msgs(root: Path, types: Iterable[str]) -> Path:
    """The .msg files of ``types`` and what they use, as the peer reads them (it would fetch them)."""
    names = set(types)
    for t in list(names):
        names.update(dependencies(t))
    for name in names:
        pkg, kind, short = name.split("/")
        path = root / pkg / kind / f"{short}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(msg_definition(name))
    return root


def start_peer(script: str, *args: str) -> Peer:
    proc = subprocess.Popen([sys.executable, "-c", script, *args], cwd=ROOT, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONUNBUFFERED": "1",
                                 "ZENOH_CONFIG_OVERRIDE": "scouting/multicast/enabled=false"})
    return Peer(proc)


@contextmanager
def router() -> Iterator[int]:
    """A Zenoh router on a free loopback port (as rmw_zenohd), no multicast scouting; yields the port."""
    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        yield port
    finally:
        session.close()
