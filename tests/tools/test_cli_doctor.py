"""`zenoh-robot doctor` against a live node, all on loopback (no scouting: the configs name the endpoints)."""
from __future__ import annotations

import json
import os
import re
import secrets
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import CLI, ROOT, Lines, free_port, python_proc
from conftest import kill_process as _stop

from zenoh_robot import SessionConfig

TALKER = r"""
import sys
from zenoh_robot import Node, msgs
with Node("talker", namespace=sys.argv[1], config=sys.argv[2]) as n:
    pub = n.create_publisher(msgs.Setpoint, "setpoint", 10)
    print("ready", flush=True)
    while True:
        pub.publish(msgs.Setpoint(msgs.Header.now(), x=1.0))
        n.spin(0.05)
"""


def _write(path: Path, config: SessionConfig) -> str:
    path.write_text(json.dumps(config.to_json5()))
    return str(path)


@pytest.fixture(scope="module")
def talker(tmp_path_factory) -> Iterator[tuple[str, list[str], Path]]:
    """(namespace, the talker's endpoints, a directory for configs)."""
    ns = f"t{secrets.token_hex(4)}"
    d = tmp_path_factory.mktemp("doctor")
    endpoints = [f"tcp/127.0.0.1:{free_port()}", f"udp/127.0.0.1:{free_port()}"]
    listen = _write(d / "listen.json5", SessionConfig(listen=endpoints, multicast_scouting=False,
                                                      shared_memory=False))
    proc = python_proc("-c", TALKER, ns, listen)
    try:
        out = Lines(proc)
        assert out.wait_for("^ready$"), out.text()
        yield ns, endpoints, d
    finally:
        _stop(proc)


def doctor(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, "doctor", *args], cwd=ROOT, capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, **(env or {})))


def _verdicts(stdout: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in stdout.splitlines():
        m = re.match(r"^(OK|WARN|FAIL) +([a-z ]+): (.*)$", line)
        if m:
            out.setdefault(m[2], []).append(f"{m[1]} {m[3]}")
    return out


def test_doctor_sees_the_peer_its_node_and_its_clock(talker):
    ns, endpoints, d = talker
    connect = _write(d / "connect.json5", SessionConfig(listen=[], connect=endpoints, multicast_scouting=False,
                                                        shared_memory=False))
    out = doctor("--zenoh", connect)
    assert out.returncode == 0, (out.stdout, out.stderr)
    v = _verdicts(out.stdout)
    assert v["session"][0].startswith("OK opened, zid "), out.stdout
    assert re.match(r"OK 1 peer\(s\), 0 router\(s\), [12] link\(s\) \((tcp|tcp, udp)\)$", v["peers"][0]), out.stdout
    assert v["discovery"] == [f"OK 1 node(s) seen: /{ns}/talker"], out.stdout
    (clock,) = v["clock"]
    m = re.match(rf"OK /{ns}/talker: ([+-][0-9.]+) ms \(median receive - source stamp over (\d+) samples", clock)
    assert m and int(m[2]) >= 3, clock
    # One host, one clock: only delivery is left (well under a second even on a loaded machine; a unit or
    # clock-source error would read seconds to years).
    assert abs(float(m[1])) < 1000.0, clock
    assert v["mtu"][0].startswith("OK batch size 65535 bytes"), out.stdout     # lo's MTU holds a whole batch
    assert v["shared memory"] == ["OK off in the config, 0 transport(s) using it"], out.stdout
    assert v["domain"][0].startswith("OK 0 "), out.stdout
    assert out.stdout.splitlines()[-1] == "7 checks: 7 ok, 0 warn, 0 fail"


def test_doctor_report_lists_platform_session_nodes_and_topics(talker):
    ns, endpoints, d = talker
    connect = _write(d / "connect2.json5", SessionConfig(listen=[], connect=endpoints, multicast_scouting=False,
                                                         shared_memory=False, batch_size=1300))
    out = doctor("--zenoh", connect, "--report", "--no-clock")
    assert out.returncode == 0, (out.stdout, out.stderr)
    for needle in ("PLATFORM INFORMATION", "eclipse-zenoh : 1.", "batch size : 1300", f"connect : {endpoints[0]}",
                   f"1 : /{ns}/talker", f"/{ns}/setpoint : zenoh_robot/Setpoint", "lo : mtu "):
        assert needle in out.stdout, out.stdout
    assert "OK   clock: not measured (--no-clock)" in out.stdout


def test_doctor_alone_warns_and_names_the_domain(talker, tmp_path):
    lonely = _write(tmp_path / "alone.json5", SessionConfig(listen=[f"tcp/127.0.0.1:{free_port()}"],
                                                            multicast_scouting=False, shared_memory=False))
    out = doctor("--zenoh", lonely, "--timeout", "0.5", env={"ZR_DOMAIN": "7"})
    assert out.returncode == 0, (out.stdout, out.stderr)     # warnings are no failure
    v = _verdicts(out.stdout)
    assert v["peers"][0].startswith("WARN no Zenoh peer"), out.stdout
    assert v["discovery"][0].startswith("WARN no other zenoh-robot node"), out.stdout
    assert v["clock"] == ["OK not measured (no remote publisher to sample)"], out.stdout
    assert v["domain"][0].startswith("OK 7 (every key under Zenoh namespace zr7)"), out.stdout


def test_doctor_fails_when_the_session_cannot_open(talker):
    ns, endpoints, d = talker
    busy = _write(d / "busy.json5", SessionConfig(listen=[endpoints[0]], multicast_scouting=False,
                                                  shared_memory=False))    # the talker holds that port
    out = doctor("--zenoh", busy)
    assert out.returncode == 1, (out.stdout, out.stderr)
    assert _verdicts(out.stdout)["session"][0].startswith("FAIL cannot open"), out.stdout
    assert out.stdout.splitlines()[-1].endswith("1 fail") and "Traceback" not in out.stderr
