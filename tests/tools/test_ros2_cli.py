"""The CLI on ROS 2's wire (``--ros2``) against an independent rmw_zenoh implementation
(zenoh-ros2-sdk, in its own process), both through a Zenoh router as rmw_zenoh nodes meet: our
``topic list/info`` see its node's topic with the ROS type, ``topic echo`` prints its String,
``topic pub`` publishes a String it hears, ``node list/info`` show it, ``service list/call`` call
its AddTwoInts. Before ``--ros2`` the CLI spoke only the envelope: it saw none of this.

zenoh-ros2-sdk would fetch .msg files from GitHub; the peer is handed the definitions (no network).
"""
from __future__ import annotations

import subprocess
from collections.abc import Iterator

import pytest
from cli_helpers import cli
from conftest import fresh_domain, kill_process, wait_for
from ros2_peer import PEER_PRELUDE, Peer, router, start_peer, write_msgs

STRING = "std_msgs/msg/String"
ADD = "example_interfaces/srv/AddTwoInts"

PEER = PEER_PRELUDE + r"""
from zenoh_ros2_sdk import ROS2Publisher, ROS2ServiceServer, ROS2Subscriber

sub = ROS2Subscriber("/sdk/heard", "std_msgs/msg/String", lambda m: out(heard=m.data), node_name="sdk_node", **common)
pub = ROS2Publisher("/sdk/chatter", "std_msgs/msg/String", node_name="sdk_node", **common)
server = ROS2ServiceServer("/sdk/add_two_ints", "example_interfaces/srv/AddTwoInts",
                           callback=lambda r: server.response_msg_class(sum=r.a + r.b),
                           request_definition="int64 a\nint64 b", response_definition="int64 sum",
                           node_name="sdk_node", **common)
out(ready=True)
n = 0
while True:
    n += 1
    pub.publish(data=f"hello {n}")
    time.sleep(0.1)
"""


@pytest.fixture(scope="module")
def peer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, int, Peer]]:
    """(router port, ROS domain, the zenoh-ros2-sdk peer)."""
    root = write_msgs(tmp_path_factory.mktemp("msgs"), [STRING])
    with router() as port:
        domain = fresh_domain()
        p = start_peer(PEER, str(root), str(port), str(domain))
        try:
            assert wait_for(lambda: p.find("ready"), 30.0), "".join(p.raw)[-3000:]
            yield port, domain, p
        finally:
            kill_process(p.proc)


def ros2_cli(peer: tuple[int, int, Peer], *args: str, timeout: float = 40.0) -> subprocess.CompletedProcess[str]:
    """``zenoh-robot <verb> --ros2 ...`` as an rmw_zenoh node: a peer connected to the router that listens and
    gossips (rmw_zenoh #929)."""
    port, domain, _ = peer
    flags = ["--ros2", "--ros-domain-id", str(domain), "-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0"]
    return cli(args[0], *flags, *args[1:], timeout=timeout)


def test_topic_list_and_info_show_the_ros2_topic_with_its_type(peer) -> None:
    listed = ros2_cli(peer, "topic", "list", "-t")
    assert listed.returncode == 0, listed.stderr
    assert f"/sdk/chatter [{STRING}]" in listed.stdout.splitlines(), listed.stdout
    info = ros2_cli(peer, "topic", "info", "/sdk/chatter", "-v")
    assert info.returncode == 0, info.stderr
    assert STRING in info.stdout and "sdk_node" in info.stdout, info.stdout


def test_node_list_and_info(peer) -> None:
    listed = ros2_cli(peer, "node", "list")
    assert listed.returncode == 0, listed.stderr
    assert "/sdk/sdk_node" in listed.stdout.splitlines(), listed.stdout
    info = ros2_cli(peer, "node", "info", "/sdk/sdk_node")
    assert info.returncode == 0, info.stderr
    assert f"/sdk/chatter: {STRING}" in info.stdout and f"/sdk/add_two_ints: {ADD}" in info.stdout, info.stdout


def test_topic_echo_decodes_its_string_with_the_graphs_type(peer) -> None:
    echo = ros2_cli(peer, "topic", "echo", "/sdk/chatter", "--once", "--duration", "20")
    assert echo.returncode == 0, echo.stderr
    assert echo.stdout.startswith("data: hello "), echo.stdout


def test_topic_hz_measures_its_rate(peer) -> None:
    hz = ros2_cli(peer, "topic", "hz", "/sdk/chatter", "--duration", "4")
    assert hz.returncode == 0, hz.stderr
    assert "average rate:" in hz.stdout, hz.stdout


def test_topic_pub_with_a_ros_type_name_is_heard(peer) -> None:
    _, _, p = peer
    pub = ros2_cli(peer, "topic", "pub", "/sdk/heard", STRING, "{data: from the cli}", "--times", "3",
                   "--max-wait", "10")
    assert pub.returncode == 0, pub.stderr
    assert wait_for(lambda: "from the cli" in p.values("heard"), 10.0), p.values("heard")


def test_service_list_and_call(peer) -> None:
    listed = ros2_cli(peer, "service", "list", "-t", "--timeout", "10")
    assert listed.returncode == 0, listed.stderr
    assert f"/sdk/add_two_ints [{ADD}]" in listed.stdout.splitlines(), listed.stdout
    call = ros2_cli(peer, "service", "call", "/sdk/add_two_ints", "{a: 20, b: 22}", "--timeout", "10")
    assert call.returncode == 0, call.stderr
    assert call.stdout.strip() == "sum: 42", call.stdout
