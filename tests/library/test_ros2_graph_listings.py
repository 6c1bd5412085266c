"""Graph listings are complete from a fresh session (issue #40, defect 2).

``node info --ros2`` once read a peer's services from one liveliness query made right after its session
opened, and missed them in about one run in four: Zenoh had delivered only part of the tokens. Listings
now read the node's graph subscriber (history, then every token as it arrives) once it has settled. Here a
zenoh-ros2-sdk peer with three services and a topic, through a router as rmw_zenoh nodes meet, is listed
ten times in a row by each listing, each in a fresh session: every run must show all of it.
"""
from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator

import pytest
from conftest import fresh_domain, kill_process, wait_for
from ros2_peer import PEER_PRELUDE, Peer, router, start_peer, write_msgs

from zenoh_robot.tools.cli.main import main

RUNS = 10
SERVICES = ("/sdk/add_two_ints", "/sdk/add_more_ints", "/sdk/add_even_more")

PEER = PEER_PRELUDE + r"""
from zenoh_ros2_sdk import ROS2Publisher, ROS2ServiceServer

pub = ROS2Publisher("/sdk/chatter", "std_msgs/msg/String", node_name="lister_peer", **common)
servers = [ROS2ServiceServer(name, "example_interfaces/srv/AddTwoInts", callback=lambda r: None,
                             request_definition="int64 a\nint64 b", response_definition="int64 sum",
                             node_name="lister_peer", **common)
           for name in ("/sdk/add_two_ints", "/sdk/add_more_ints", "/sdk/add_even_more")]
out(ready=True)
sys.stdin.readline()
"""


@pytest.fixture(scope="module")
def peer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, int]]:
    root = write_msgs(tmp_path_factory.mktemp("msgs"), ["std_msgs/msg/String"])
    with router() as port:
        domain = fresh_domain()
        p: Peer = start_peer(PEER, str(root), str(port), str(domain))
        try:
            assert wait_for(lambda: p.find("ready"), 30.0), "".join(p.raw)[-3000:]
            yield port, domain
        finally:
            kill_process(p.proc)


def run(peer: tuple[int, int], *args: str) -> str:
    """One CLI command in this process, in its own fresh session, as an rmw_zenoh node (connect and listen)."""
    port, domain = peer
    flags = ["--ros2", "--ros-domain-id", str(domain), "-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0"]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([args[0], *flags, *args[1:]])
    assert code == 0, out.getvalue()
    return out.getvalue()


def test_node_info_lists_every_service_every_time(peer: tuple[int, int]) -> None:
    for _ in range(RUNS):
        text = run(peer, "node", "info", "/sdk/lister_peer")
        servers = text.split("Service Servers:")[1].split("Service Clients:")[0]
        assert all(f"{name}: example_interfaces/srv/AddTwoInts" in servers for name in SERVICES), text
        assert "/sdk/chatter: std_msgs/msg/String" in text.split("Publishers:")[1], text


def test_service_list_shows_every_server_every_time(peer: tuple[int, int]) -> None:
    for _ in range(RUNS):
        listed = run(peer, "service", "list").split()
        assert set(SERVICES) <= set(listed), listed


def test_topic_and_node_lists_are_complete_every_time(peer: tuple[int, int]) -> None:
    for _ in range(RUNS):
        assert "/sdk/chatter" in run(peer, "topic", "list").split()
        assert "/sdk/lister_peer" in run(peer, "node", "list").split()
