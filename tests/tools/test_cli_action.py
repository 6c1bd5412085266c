"""`zenoh-robot action list|info|type|send_goal`, and actions in `node info`, against live nodes in another
process: on the envelope wire (the module's talker), and on the ROS 2 wire through a router.
"""
from __future__ import annotations

import re
import subprocess

from cli_helpers import cli
from conftest import Lines, fresh_domain, kill_process, python_proc
from ros2_peer import router as ros2_router

SERVER = r"""
import sys, time
from zenoh_robot import Node
from zenoh_robot.actions import GoalResponse
from zenoh_robot.ros2 import ros2_action_type

Fibonacci = ros2_action_type("example_interfaces/action/Fibonacci")

def execute(handle):
    seq = [0, 1]
    for i in range(1, handle.request.order):
        seq.append(seq[i] + seq[i - 1])
        handle.publish_feedback(Fibonacci.Feedback(sequence=list(seq)))
    handle.succeed()
    return Fibonacci.Result(sequence=seq)

def nodes(ns):
    if len(sys.argv) < 3:
        return Node("talker", namespace=ns), Node("watcher", namespace=ns)
    from zenoh_robot.session_config import SessionConfig
    from zenoh_robot.wire.ros2 import ros2_wire
    port, domain = int(sys.argv[2]), int(sys.argv[3])
    config = SessionConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"],
                           multicast_scouting=False)
    return (Node("talker", namespace=ns, config=config, wire=ros2_wire(domain)),
            Node("watcher", namespace=ns, config=config, wire=ros2_wire(domain)))

talker, watcher = nodes(sys.argv[1])
with talker, watcher:
    talker.create_action_server(Fibonacci, "fibonacci", execute,
                                goal_callback=lambda g: GoalResponse.ACCEPT if g.order < 40 else GoalResponse.REJECT)
    watcher.create_action_client(Fibonacci, "fibonacci")
    print("ready", flush=True)
    talker.spin()
"""
TALKER = SERVER     # conftest's `talker` fixture runs it (envelope wire, a domain of the module's own)
FIB = "example_interfaces/action/Fibonacci"


def _ok(out: subprocess.CompletedProcess[str]) -> list[str]:
    assert out.returncode == 0, (out.stdout, out.stderr)
    return out.stdout.splitlines()


def test_action_list_info_and_type(talker: str) -> None:
    name = f"/{talker}/fibonacci"
    assert _ok(cli("action", "list")) == [name]
    assert _ok(cli("action", "list", "-t")) == [f"{name} [{FIB}]"]
    assert _ok(cli("action", "list", "-c")) == ["1"]
    assert _ok(cli("action", "info", name)) == [f"Action: {name}", "Action clients: 1", f"    /{talker}/watcher",
                                                "Action servers: 1", f"    /{talker}/talker"]
    assert _ok(cli("action", "type", name)) == [FIB]


def test_send_goal_prints_feedback_result_and_status(talker: str) -> None:
    lines = _ok(cli("action", "send_goal", f"/{talker}/fibonacci", FIB, "{order: 3}", "--feedback"))
    text = "\n".join(lines)
    assert lines[:2] == ["Sending goal:", "    order: 3"]
    assert re.search(r"^Goal accepted with ID: [0-9a-f]{32}$", text, re.M), text
    assert lines.count("Feedback:") == 2
    assert text.index("Goal accepted") < text.index("Feedback:") < text.index("Result:")
    result = lines[lines.index("Result:") + 1:]
    assert result[:5] == ["    sequence:", "    - 0", "    - 1", "    - 1", "    - 2"]
    assert lines[-1] == "Goal finished with status: SUCCEEDED"
    plain = _ok(cli("action", "send_goal", f"/{talker}/fibonacci", FIB, "{order: 2}"))
    assert "Feedback:" not in plain and plain[-1] == "Goal finished with status: SUCCEEDED"


def test_a_rejected_goal_and_mistakes_are_one_line(talker: str) -> None:
    out = cli("action", "send_goal", f"/{talker}/fibonacci", FIB, "{order: 50}")
    assert out.returncode == 1 and out.stdout.splitlines()[-1] == "Goal was rejected."
    missing = cli("action", "info", f"/{talker}/fibonaci")
    assert missing.returncode == 1 and "Traceback" not in missing.stderr
    assert missing.stderr.strip().endswith(f"(did you mean /{talker}/fibonacci?)"), missing.stderr
    unknown = cli("action", "send_goal", f"/{talker}/fibonacci", "zr_test/action/Nope", "{}")
    assert unknown.returncode == 1 and "--action FILE" in unknown.stderr and "Traceback" not in unknown.stderr
    bad = cli("action", "send_goal", f"/{talker}/fibonacci", FIB, "{order: many}")
    assert bad.returncode == 1 and "order" in bad.stderr and "Traceback" not in bad.stderr


def test_node_info_shows_actions_not_their_parts(talker: str) -> None:
    lines = _ok(cli("node", "info", f"/{talker}/talker", "--no-params"))
    at = lines.index("  Action Servers:")
    assert lines[at + 1] == f"    /{talker}/fibonacci: {FIB}"
    assert not [line for line in lines if "/_action/" in line], lines
    watcher = _ok(cli("node", "info", f"/{talker}/watcher", "--no-params"))
    assert watcher[watcher.index("  Action Clients:") + 1] == f"    /{talker}/fibonacci: {FIB}"


def test_action_commands_on_the_ros2_wire() -> None:
    domain = fresh_domain()
    with ros2_router() as port:
        proc = python_proc("-c", SERVER, "ros", str(port), str(domain))
        try:
            assert Lines(proc).wait_for("^ready")
            flags = ("--ros-domain-id", str(domain), "-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0")
            assert _ok(cli("action", *flags, "list", "-t")) == [f"/ros/fibonacci [{FIB}]"]
            lines = _ok(cli("action", *flags, "send_goal", "/ros/fibonacci", FIB, "{order: 4}", "-f"))
            assert lines[-1] == "Goal finished with status: SUCCEEDED" and lines.count("Feedback:") == 3
            info = _ok(cli("node", *flags, "info", "/ros/talker"))
            assert info[info.index("  Action Servers:") + 1] == f"    /ros/fibonacci: {FIB}"
            assert not [line for line in info if "/_action/" in line], info
        finally:
            kill_process(proc)


def test_listings_hide_the_parts_unless_asked(talker: str) -> None:
    """As ros2 topic/service list: an action's five parts are hidden names, shown on request."""
    base = f"/{talker}/fibonacci/_action/"
    assert not [t for t in _ok(cli("topic", "list")) if "/_action/" in t]
    assert {base + "feedback", base + "status"} <= set(_ok(cli("topic", "list", "--include-hidden-topics")))
    assert not [s for s in _ok(cli("service", "list")) if "/_action/" in s]
    assert {base + p for p in ("send_goal", "cancel_goal", "get_result")} <= set(
        _ok(cli("service", "list", "--include-hidden-services")))
    # topic find too (it read a flag only `list` had: a traceback once an action was on the graph)
    status = "action_msgs/msg/GoalStatusArray"
    assert base + "status" not in _ok(cli("topic", "find", status))
    assert base + "status" in _ok(cli("topic", "find", status, "--include-hidden-topics"))


def test_interface_show_of_an_action() -> None:
    lines = _ok(cli("interface", "show", "--ros2", FIB))
    assert lines[:5] == ["int32 order 0", "---", "int32[] sequence", "---", "int32[] sequence"]
    assert lines[5:] == ["# send_goal RIHS01_d1a57fb2a4afe8c21e34fb10db206f16ce6729b28531141472df92277c55b557",
                         "# get_result RIHS01_1b0de0d5d29dc955d92f546706568428632771db13ec84c15ec1c1a59f424a57",
                         "# feedback RIHS01_c1de71afd52e49a89c53d8262366884185bc0a02f78ce051c4e46b0a7fe59bb2"]
