"""A `topic pub` process's topic is on the graph like any other (issue #40, defect 3).

``ros2 topic pub /chatter ...`` is listed by ``ros2 topic list`` and ``ros2 topic info``; ours was hidden
(only ``-a`` showed it) because the listing left out every CLI tool's node, not just its own. Two CLI
processes here, through a router: one publishing, one listing, on the envelope and on ROS 2's wire.
"""
from __future__ import annotations

import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import fresh_domain, kill_process, wait_for
from ros2_peer import router

from zenoh_robot import Node
from zenoh_robot.session_config import SessionConfig
from zenoh_robot.wire import ENVELOPE
from zenoh_robot.wire.ros2 import ros2_wire

ROOT = Path(__file__).resolve().parents[2]
# Through the router only: no multicast scouting into other tests' sessions.
ENV = {**os.environ, "ZENOH_CONFIG_OVERRIDE": "scouting/multicast/enabled=false"}
CLI = [sys.executable, "-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())"]


def _flags(port: int, domain: int | None) -> list[str]:
    flags = ["-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0"]
    return flags + (["--ros2", "--ros-domain-id", str(domain)] if domain is not None else [])


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("ros2", [False, True], ids=["envelope", "ros2"])
def test_topic_pub_is_listed_and_found_by_info(ros2: bool) -> None:
    topic = f"/pub_{secrets.token_hex(3)}/chatter"
    domain = fresh_domain() if ros2 else None
    type_name = "std_msgs/msg/String" if ros2 else "std_msgs/String"
    with router() as port:
        flags = _flags(port, domain)
        pub = subprocess.Popen([*CLI, "topic", "pub", *flags, topic, type_name, "{data: hi}", "-r", "5"],
                               cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            config = SessionConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"],
                                   multicast_scouting=False)
            with Node("pub_watch", config=config, wire=ros2_wire(domain) if domain is not None else ENVELOPE) as w:
                assert wait_for(lambda: bool(w.get_publishers_info_by_topic(topic)), 30.0), pub.stderr
            listed = _cli("topic", "list", *flags)
            assert listed.returncode == 0, listed.stderr
            assert topic in listed.stdout.split(), listed.stdout
            info = _cli("topic", "info", *flags, topic)
            assert info.returncode == 0, info.stderr
            assert "Publisher count: 1" in info.stdout, info.stdout
        finally:
            kill_process(pub)
