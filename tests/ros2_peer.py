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


# -- rmw_zenoh's reading of a token (rmw_zenoh_cpp/src/detail/liveliness_utils.cpp, parse_token) ------------
# Written from rmw_zenoh's source, not from zenoh_robot's reader: fields split on '/', each demangled by
# replacing every '%' with '/' and nothing else. No leading slash is added (zenoh-ros2-sdk's demangle_name
# adds one; rmw_zenoh does not), so a token that drops it names another service, as it would in ROS 2.
RMW_FIELDS = ("admin_space", "domain_id", "zid", "nid", "id", "entity", "enclave", "namespace", "node_name",
              "name", "type", "type_hash", "qos")


def rmw_demangle(text: str) -> str:
    return text.replace("%", "/")


def rmw_zenoh_entity(key: str) -> dict[str, str] | None:
    """A token as rmw_zenoh's graph cache records it; None for what rmw_zenoh would refuse."""
    parts = key.split("/")
    if parts[0] != "@ros2_lv" or len(parts) < 9:
        return None
    if parts[5] == "NN":
        if len(parts) != 9:
            return None
    elif parts[5] not in ("MP", "MS", "SS", "SC") or len(parts) != 13:
        return None
    entity = dict(zip(RMW_FIELDS, parts, strict=False))   # a node token has no name, type, hash or QoS
    for field in ("enclave", "namespace", "node_name", "name", "type", "type_hash"):
        if field in entity:
            entity[field] = rmw_demangle(entity[field])
    return entity


def rmw_zenoh_service_available(keys: Iterable[str], fqn: str, dds_type: str, type_hash: str) -> bool:
    """rmw_service_server_is_available as rmw_zenoh's graph answers it: an SS token whose demangled name
    is the client's fully qualified name (rcl always asks with one), of the same type and hash."""
    for key in keys:
        e = rmw_zenoh_entity(key)
        if e and e["entity"] == "SS" and e["name"] == fqn and e["type"] == dds_type and e["type_hash"] == type_hash:
            return True
    return False


class RmwZenohGraph:
    """rmw_zenoh's graph cache in miniature, on a plain Zenoh session: a liveliness subscriber with history
    on ``@ros2_lv/<domain>/**`` (rmw_zenoh: an initial liveliness get, then the subscriber), each token
    kept as :func:`rmw_zenoh_entity` reads it."""

    def __init__(self, session: zenoh.Session, domain: int) -> None:
        self._lock = threading.Lock()
        self._entities: dict[str, dict[str, str]] = {}
        self._sub = session.liveliness().declare_subscriber(f"@ros2_lv/{domain}/**", self._on_token, history=True)

    def _on_token(self, sample: Any) -> None:
        key = str(sample.key_expr)
        entity = rmw_zenoh_entity(key)
        with self._lock:
            if sample.kind == zenoh.SampleKind.DELETE:
                self._entities.pop(key, None)
            elif entity is not None:
                self._entities[key] = entity

    def keys(self) -> list[str]:
        with self._lock:
            return list(self._entities)

    def entities(self, *kinds: str) -> list[dict[str, str]]:
        with self._lock:
            return [e for e in self._entities.values() if not kinds or e["entity"] in kinds]

    def close(self) -> None:
        self._sub.undeclare()


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
