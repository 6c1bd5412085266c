"""Actions on rmw_zenoh's wire: the derived types' names and RIHS01 hashes as ROS 2 computes them, the
five parts' keys and liveliness tokens as rmw_zenoh writes and reads them, a goal between two of our
nodes through a router, and a goal each way with an independent implementation (zenoh-ros2-sdk, in its
own process).

The reference hashes are ROS 2's own: its "Understanding actions" tutorial prints, with
``ros2 action info -v /turtle1/rotate_absolute``, the hash of every part of
turtlesim_msgs/action/RotateAbsolute (``float32 theta --- float32 delta --- float32 remaining``).
rmw_zenoh has no action entities (docs/design.md, "Actions": "actions are composed of several services
and pub/sub"): the parts are services and topics named ``<action>/_action/<part>``, so their keys and
tokens are the documented service and topic forms. zenoh-ros2-sdk 0.1.8 has no actions: the peer composes
a client and a server from its service clients, servers, publishers and subscribers, as rcl_action composes
them from rcl's.
"""
from __future__ import annotations

import json
import struct
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import fresh_domain, kill_process, python_proc, wait_for
from ros2_peer import PEER_PRELUDE, RmwZenohGraph, rmw_zenoh_service_available, write_msgs
from ros2_peer import router as ros2_router

from zenoh_robot import Node
from zenoh_robot.actions import CancelResponse, GoalStatus, ServerGoalHandle
from zenoh_robot.ros2 import ros2_action_type
from zenoh_robot.services import service_data_key
from zenoh_robot.session_config import SessionConfig
from zenoh_robot.wire.ros2 import Ros2Graph, encode_ros2_qos, ros2_wire

ROTATE = "turtlesim_msgs/action/RotateAbsolute"
ROTATE_TEXT = "float32 theta\n---\nfloat32 delta\n---\nfloat32 remaining\n"
# ROS 2's tutorial, `ros2 action info -v /turtle1/rotate_absolute` (Kilted/Rolling), verbatim.
ROS2_HASHES = {
    "send_goal": "RIHS01_3d5d3cfcbb721f88038eaedcd4af95565360a82b36f1983e3a6c7448d2d18fbe",
    "cancel_goal": "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
    "get_result": "RIHS01_f96fd02477be2a47122fca142e960d407b24850c6eac72047872ba764473c4ef",
    "feedback": "RIHS01_bef10993e1ee82b35f99f7e390bac1e6cc64e2a3090536887832e122aa71f1b5",
    "status": "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e",
}
DDS = {
    "send_goal": "turtlesim_msgs::action::dds_::RotateAbsolute_SendGoal_",
    "cancel_goal": "action_msgs::srv::dds_::CancelGoal_",
    "get_result": "turtlesim_msgs::action::dds_::RotateAbsolute_GetResult_",
    "feedback": "turtlesim_msgs::action::dds_::RotateAbsolute_FeedbackMessage_",
    "status": "action_msgs::msg::dds_::GoalStatusArray_",
}
SERVICES = ("send_goal", "cancel_goal", "get_result")
WAIT = 15.0

Rotate = ros2_action_type(ROTATE, ROTATE_TEXT)


def _hashes(action: Any) -> dict[str, str]:
    return {"send_goal": action.send_goal.hash, "cancel_goal": action.cancel_goal.hash,
            "get_result": action.get_result.hash, "feedback": action.feedback_message._type_hash,
            "status": action.goal_status_array._type_hash}


# -- byte level -------------------------------------------------------------------------------------------
def test_derived_types_are_named_and_hashed_as_ros2_does() -> None:
    assert _hashes(Rotate) == ROS2_HASHES
    assert {"send_goal": Rotate.send_goal.dds_name, "cancel_goal": Rotate.cancel_goal.dds_name,
            "get_result": Rotate.get_result.dds_name, "feedback": Rotate.feedback_message._zr_ros2.dds_name,
            "status": Rotate.goal_status_array._zr_ros2.dds_name} == DDS
    assert Rotate.send_goal.request._type_name == f"{ROTATE}_SendGoal_Request"
    assert [f.name for f in Rotate.send_goal.request._fields_spec] == ["goal_id", "goal"]
    assert [f.name for f in Rotate.send_goal.response._fields_spec] == ["accepted", "stamp"]
    assert [f.name for f in Rotate.get_result.response._fields_spec] == ["status", "result"]
    assert [f.name for f in Rotate.feedback_message._fields_spec] == ["goal_id", "feedback"]
    # example_interfaces/action/Fibonacci (bundled): the hashes rmw_zenoh peers announce for it.
    fib = ros2_action_type("example_interfaces/action/Fibonacci")
    assert (fib.send_goal.hash, fib.get_result.hash, fib.feedback_message._type_hash) == (
        "RIHS01_d1a57fb2a4afe8c21e34fb10db206f16ce6729b28531141472df92277c55b557",
        "RIHS01_1b0de0d5d29dc955d92f546706568428632771db13ec84c15ec1c1a59f424a57",
        "RIHS01_c1de71afd52e49a89c53d8262366884185bc0a02f78ce051c4e46b0a7fe59bb2")


def test_the_sdk_hashes_goal_status_array_as_we_do() -> None:
    from zenoh_ros2_sdk.utils import compute_type_hash_from_msg

    from zenoh_robot.ros2 import dependencies, msg_definition
    deps = {t: msg_definition(t) for t in dependencies("action_msgs/msg/GoalStatusArray")}
    assert compute_type_hash_from_msg("action_msgs/msg/GoalStatusArray",
                                      msg_definition("action_msgs/msg/GoalStatusArray"),
                                      dependencies=deps) == ROS2_HASHES["status"]


def test_a_bad_action_definition_is_named() -> None:
    from zenoh_robot.ros2 import Ros2TypeError
    with pytest.raises(Ros2TypeError, match="PKG/action/NAME"):
        ros2_action_type("turtlesim_msgs/srv/RotateAbsolute", ROTATE_TEXT)
    with pytest.raises(Ros2TypeError, match="two '---'"):
        ros2_action_type("zr_test/action/Half", "int32 a\n---\nint32 b\n")
    with pytest.raises(Ros2TypeError, match="no definition"):
        ros2_action_type("zr_test/action/Unknown")


def test_cdr_of_the_goal_request_and_status() -> None:
    from zenoh_robot.ros2 import decode_cdr, encode_cdr
    goal_id = bytes(range(16))
    request = Rotate.send_goal.request(goal_id=Rotate.uuid(uuid=goal_id), goal=Rotate.Goal(theta=1.5))
    assert encode_cdr(request) == b"\x00\x01\x00\x00" + goal_id + struct.pack("<f", 1.5)
    status = Rotate.goal_status_array(status_list=[Rotate.goal_status(
        goal_info=Rotate.goal_info(goal_id=Rotate.uuid(uuid=goal_id), stamp=Rotate.time(sec=7, nanosec=9)),
        status=int(GoalStatus.STATUS_EXECUTING))])
    data = encode_cdr(status)
    assert data == b"\x00\x01\x00\x00" + struct.pack("<I", 1) + goal_id + struct.pack("<iIb", 7, 9, 2)
    assert decode_cdr(Rotate.goal_status_array, data) == status


def test_the_five_keys_and_tokens_are_rmw_zenohs() -> None:
    name = "/turtle1/rotate_absolute"
    assert {p: service_data_key(3, f"{name}/_action/{p}", getattr(Rotate, p)) for p in SERVICES} == {
        p: f"3/turtle1/rotate_absolute/_action/{p}/{DDS[p]}/{ROS2_HASHES[p]}" for p in SERVICES}
    wire = ros2_wire(3)
    from zenoh_robot.message import type_support
    assert wire.data_key("turtle1/rotate_absolute/_action/status", type_support(Rotate.goal_status_array)) == \
        f"3/turtle1/rotate_absolute/_action/status/{DDS['status']}/{ROS2_HASHES['status']}"
    from zenoh_robot.actions.server import STATUS_QOS
    token = Ros2Graph(3).entity_token("MP", "ab", 1, "/", "turtlesim", f"{name}/_action/status",
                                      "action_msgs/msg/GoalStatusArray", ROS2_HASHES["status"], STATUS_QOS)
    assert token.split("/")[5:] == ["MP", "%", "%", "turtlesim", "%turtle1%rotate_absolute%_action%status",
                                    DDS["status"], ROS2_HASHES["status"], encode_ros2_qos(STATUS_QOS)]
    # reliable, transient local, keep last 1: what `ros2 action info -v` shows for the status topic.
    assert encode_ros2_qos(STATUS_QOS).startswith("1:1:1,1:")


# -- live, through a router as rmw_zenoh nodes meet ----------------------------------------------------------
@pytest.fixture
def router() -> Iterator[int]:
    with ros2_router() as port:
        yield port


def _node(name: str, port: int, domain: int, namespace: str | None = None) -> Node:
    config = SessionConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"],
                           multicast_scouting=False)
    return Node(name, namespace, config=config, wire=ros2_wire(domain))


def _spin(*nodes: Node) -> list[threading.Thread]:
    threads = [threading.Thread(target=n.spin, daemon=True) for n in nodes]
    for t in threads:
        t.start()
    return threads


def rotate(handle: ServerGoalHandle) -> Any:
    theta = float(handle.request.theta)
    for step in range(3):
        if handle.is_cancel_requested:
            handle.canceled()
            return Rotate.Result(delta=-1.0)
        handle.publish_feedback(Rotate.Feedback(remaining=theta - step))
    handle.succeed()
    return Rotate.Result(delta=theta)


def test_a_goal_between_our_nodes_and_the_graph_rmw_zenoh_reads(router: int) -> None:
    domain = fresh_domain()
    with _node("turtlesim", router, domain) as server_node, _node("teleop", router, domain) as client_node:
        threads = _spin(server_node, client_node)
        server_node.create_action_server(Rotate, "/turtle1/rotate_absolute", rotate,
                                         cancel_callback=lambda h: CancelResponse.ACCEPT)
        client = client_node.create_action_client(Rotate, "/turtle1/rotate_absolute")
        graph = RmwZenohGraph(client_node.session, domain)
        try:
            assert client.wait_for_server(WAIT)
            # Every part as rmw_zenoh's graph cache reads it: fully qualified names, types, hashes, QoS.
            for part in SERVICES:
                assert wait_for(lambda p=part: rmw_zenoh_service_available(
                    graph.keys(), f"/turtle1/rotate_absolute/_action/{p}", DDS[p], ROS2_HASHES[p]), WAIT), part

            def entities() -> set[tuple[str, str, str, str]]:
                return {(e["entity"], e["node_name"], e["name"].rsplit("/", 1)[1], e["type_hash"])
                        for e in graph.entities() if "/_action/" in e.get("name", "")}
            want = {(k, "turtlesim", p, ROS2_HASHES[p]) for k, p in
                    [("SS", "send_goal"), ("SS", "cancel_goal"), ("SS", "get_result"), ("MP", "feedback"),
                     ("MP", "status")]}
            want |= {(k, "teleop", p, ROS2_HASHES[p]) for k, p in
                     [("SC", "send_goal"), ("SC", "cancel_goal"), ("SC", "get_result"), ("MS", "feedback"),
                      ("MS", "status")]}
            assert wait_for(lambda: want <= entities(), WAIT), want - entities()
            status_qos = {e["qos"] for e in graph.entities("MP") if e["name"].endswith("/_action/status")}
            assert all(q.startswith("1:1:1,1:") for q in status_qos), status_qos

            feedback: list[float] = []
            handle = client.send_goal_async(Rotate.Goal(theta=3.0),
                                            feedback_callback=lambda m: feedback.append(m.feedback.remaining)
                                            ).result(WAIT)
            assert handle.accepted
            result = handle.get_result_async().result(WAIT)
            assert (result.status, result.result.delta) == (GoalStatus.STATUS_SUCCEEDED, 3.0)
            assert wait_for(lambda: handle.status == GoalStatus.STATUS_SUCCEEDED, WAIT)
        finally:
            graph.close()
    for t in threads:
        t.join(timeout=2.0)


# -- the independent peer: zenoh-ros2-sdk sends a goal to our server ------------------------------------------
SDK_ACTION_CLIENT = PEER_PRELUDE + r"""
import numpy as np
from zenoh_ros2_sdk import ROS2ServiceClient, ROS2Subscriber
send_hash, result_hash, feedback_hash = sys.argv[4:7]
name = "/turtle1/rotate_absolute"
node = dict(common, namespace="/")
# The nested Goal/Result/Feedback structs of one float32 each, written inline: the same CDR bytes.
feedback = ROS2Subscriber(name + "/_action/feedback", "turtlesim_msgs/action/RotateAbsolute_FeedbackMessage",
                          callback=lambda m: out(feedback=float(m.remaining), goal=bytes(m.goal_id.uuid).hex()),
                          msg_definition="unique_identifier_msgs/UUID goal_id\nfloat32 remaining",
                          type_hash=feedback_hash, node_name="sdk_teleop", **node)
status = ROS2Subscriber(name + "/_action/status", "action_msgs/msg/GoalStatusArray",
                        callback=lambda m: out(status=[[bytes(s.goal_info.goal_id.uuid).hex(), int(s.status)]
                                                       for s in m.status_list]),
                        node_name="sdk_teleop_status", **node)
send = ROS2ServiceClient(name + "/_action/send_goal", "turtlesim_msgs/action/RotateAbsolute_SendGoal",
                         request_definition="unique_identifier_msgs/UUID goal_id\nfloat32 theta",
                         response_definition="bool accepted\nbuiltin_interfaces/Time stamp",
                         type_hash=send_hash, node_name="sdk_teleop_send", timeout=5.0, **node)
result = ROS2ServiceClient(name + "/_action/get_result", "turtlesim_msgs/action/RotateAbsolute_GetResult",
                           request_definition="unique_identifier_msgs/UUID goal_id",
                           response_definition="int8 status\nfloat32 delta",
                           type_hash=result_hash, node_name="sdk_teleop_result", timeout=10.0, **node)
out(keys=[send.keyexpr, result.keyexpr])
UUID = send.session_mgr.store.types["unique_identifier_msgs/msg/UUID"]
goal_id = UUID(uuid=np.frombuffer(bytes(range(1, 17)), dtype=np.uint8))
sys.stdin.readline()     # the test says when our server is up
for _ in range(40):
    reply = send.call(goal_id=goal_id, theta=2.5)
    if reply is not None:
        out(accepted=bool(reply.accepted), sec=int(reply.stamp.sec))
        break
    time.sleep(0.25)
reply = result.call(goal_id=goal_id)
out(result_status=int(reply.status) if reply is not None else None,
    delta=float(reply.delta) if reply is not None else None)
sys.stdin.readline()
"""


def test_an_sdk_client_sends_a_goal_to_our_server(router: int, tmp_path: Path) -> None:
    domain = fresh_domain()
    msgs = write_msgs(tmp_path / "msgs", ["action_msgs/msg/GoalStatusArray", "unique_identifier_msgs/msg/UUID",
                                          "builtin_interfaces/msg/Time"])
    started = threading.Event()

    def execute(handle: ServerGoalHandle) -> Any:
        # Feedback is sent once the peer's feedback subscription is matched (else it is for nobody).
        wait_for(lambda: server.get_feedback_subscription_count() >= 1, WAIT)
        started.set()
        return rotate(handle)
    with _node("turtlesim", router, domain) as node:
        threads = _spin(node)
        server = node.create_action_server(Rotate, "/turtle1/rotate_absolute", execute)
        peer = python_proc("-c", SDK_ACTION_CLIENT, str(msgs), str(router), str(domain),
                           ROS2_HASHES["send_goal"], ROS2_HASHES["get_result"], ROS2_HASHES["feedback"],
                           stdin=subprocess.PIPE)
        lines: list[dict[str, Any]] = []

        def read() -> None:
            assert peer.stdout is not None
            for line in peer.stdout:
                if line.startswith("{"):
                    lines.append(json.loads(line))
        threading.Thread(target=read, daemon=True).start()
        try:
            assert wait_for(lambda: any("keys" in d for d in lines), 30.0), lines
            keys = next(d["keys"] for d in lines if "keys" in d)
            assert keys == [s.key for s in node.services if "/_action/send_goal" in s.key or
                            "/_action/get_result" in s.key], keys
            assert peer.stdin is not None
            peer.stdin.write("go\n")
            peer.stdin.flush()
            assert wait_for(lambda: any("result_status" in d for d in lines), 40.0), lines
            accepted = next(d for d in lines if "accepted" in d)
            assert accepted["accepted"] and abs(accepted["sec"] - time.time()) < 3600
            final = next(d for d in lines if "result_status" in d)
            assert final == {"result_status": int(GoalStatus.STATUS_SUCCEEDED), "delta": 2.5}
            goal = bytes(range(1, 17)).hex()
            assert [d["feedback"] for d in lines if "feedback" in d and d["goal"] == goal] == [2.5, 1.5, 0.5]
            statuses = [s for d in lines if "status" in d for g, s in d["status"] if g == goal]
            assert statuses and statuses[-1] == int(GoalStatus.STATUS_SUCCEEDED)
            assert server.executions == 1
        finally:
            kill_process(peer)
    for t in threads:
        t.join(timeout=2.0)


def test_a_malformed_goal_is_refused_with_a_reason(router: int) -> None:
    """Bytes that are not a SendGoal request (cut short) never reach the goal callback: the caller gets an
    error naming the type, and nothing runs."""
    from zenoh_robot.wire.ros2 import pack_attachment

    domain = fresh_domain()
    with _node("turtlesim", router, domain) as node:
        threads = _spin(node)
        server = node.create_action_server(Rotate, "/turtle1/rotate_absolute", rotate)
        key = next(s.key for s in node.services if "/_action/send_goal/" in s.key)
        replies = list(node.session.get(key, payload=b"\x00\x01\x00\x00" + bytes(10),
                                        attachment=pack_attachment(1, time.time_ns(), bytes(16)), timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is None
        assert "RotateAbsolute_SendGoal" in replies[0].err.payload.to_bytes().decode()
        assert server.executions == 0 and server.goal_handles() == []
    for t in threads:
        t.join(timeout=2.0)


# -- the independent peer serves: our client sends it a goal ------------------------------------------------
SDK_ACTION_SERVER = PEER_PRELUDE + r"""
import numpy as np
from zenoh_ros2_sdk import ROS2Publisher, ROS2ServiceServer
send_hash, result_hash, feedback_hash = sys.argv[4:7]
name = "/turtle1/rotate_absolute"
node = dict(common, namespace="/")
goals = {}          # goal id (hex) -> (theta, done event)

feedback = ROS2Publisher(name + "/_action/feedback", "turtlesim_msgs/action/RotateAbsolute_FeedbackMessage",
                         msg_definition="unique_identifier_msgs/UUID goal_id\nfloat32 remaining",
                         type_hash=feedback_hash, node_name="sdk_turtlesim_fb", **node)
status = ROS2Publisher(name + "/_action/status", "action_msgs/msg/GoalStatusArray",
                       node_name="sdk_turtlesim_status", **node)
store = status.session_mgr.store
UUID, Time = store.types["unique_identifier_msgs/msg/UUID"], store.types["builtin_interfaces/msg/Time"]
GoalInfo, GoalStatus = store.types["action_msgs/msg/GoalInfo"], store.types["action_msgs/msg/GoalStatus"]

def publish_status(goal_id, code):
    info = GoalInfo(goal_id=UUID(uuid=np.frombuffer(goal_id, dtype=np.uint8)), stamp=Time(sec=1, nanosec=2))
    status.publish(status_list=[GoalStatus(goal_info=info, status=code)])

def run(goal_id, theta, done):
    publish_status(goal_id, 2)
    for step in range(3):
        time.sleep(0.1)
        feedback.publish(goal_id=UUID(uuid=np.frombuffer(goal_id, dtype=np.uint8)), remaining=theta - step)
    publish_status(goal_id, 4)
    done.set()

def on_goal(req):
    goal_id = bytes(req.goal_id.uuid)
    done = threading.Event()
    goals[goal_id.hex()] = (float(req.theta), done)
    out(goal=goal_id.hex(), theta=float(req.theta))
    threading.Thread(target=run, args=(goal_id, float(req.theta), done), daemon=True).start()
    return send.response_msg_class(accepted=True, stamp=Time(sec=5, nanosec=6))

def on_result(req):
    theta, done = goals[bytes(req.goal_id.uuid).hex()]
    done.wait(10)
    return result.response_msg_class(status=4, delta=theta)

def on_cancel(req):
    out(cancel=bytes(req.goal_info.goal_id.uuid).hex())
    return cancel.response_msg_class(return_code=1, goals_canceling=[])

send = ROS2ServiceServer(name + "/_action/send_goal", "turtlesim_msgs/action/RotateAbsolute_SendGoal", callback=on_goal,
                         request_definition="unique_identifier_msgs/UUID goal_id\nfloat32 theta",
                         response_definition="bool accepted\nbuiltin_interfaces/Time stamp",
                         type_hash=send_hash, node_name="sdk_turtlesim_send", **node)
result = ROS2ServiceServer(name + "/_action/get_result", "turtlesim_msgs/action/RotateAbsolute_GetResult",
                           callback=on_result, request_definition="unique_identifier_msgs/UUID goal_id",
                           response_definition="int8 status\nfloat32 delta",
                           type_hash=result_hash, node_name="sdk_turtlesim_result", **node)
# CancelGoal is a real service type: the SDK computes its hash itself.
cancel = ROS2ServiceServer(name + "/_action/cancel_goal", "action_msgs/srv/CancelGoal", callback=on_cancel,
                           request_definition="action_msgs/GoalInfo goal_info",
                           response_definition="int8 return_code\naction_msgs/GoalInfo[] goals_canceling",
                           node_name="sdk_turtlesim_cancel", **node)
out(cancel_key=cancel.keyexpr)
sys.stdin.readline()
"""


def test_our_client_sends_a_goal_to_an_sdk_server(router: int, tmp_path: Path) -> None:
    domain = fresh_domain()
    msgs = write_msgs(tmp_path / "msgs", ["action_msgs/msg/GoalStatusArray", "unique_identifier_msgs/msg/UUID",
                                          "builtin_interfaces/msg/Time"])
    peer = python_proc("-c", SDK_ACTION_SERVER, str(msgs), str(router), str(domain), ROS2_HASHES["send_goal"],
                       ROS2_HASHES["get_result"], ROS2_HASHES["feedback"], stdin=subprocess.PIPE)
    lines: list[dict[str, Any]] = []

    def read() -> None:
        assert peer.stdout is not None
        for line in peer.stdout:
            if line.startswith("{"):
                lines.append(json.loads(line))
    threading.Thread(target=read, daemon=True).start()
    try:
        assert wait_for(lambda: any("cancel_key" in d for d in lines), 30.0), lines
        # The SDK's own hash of action_msgs/srv/CancelGoal is in its key: the same as ours (and ROS 2's).
        cancel_key = next(d["cancel_key"] for d in lines if "cancel_key" in d)
        assert cancel_key == f"{domain}/turtle1/rotate_absolute/_action/cancel_goal/{DDS['cancel_goal']}/" \
                             f"{ROS2_HASHES['cancel_goal']}"
        with _node("teleop", router, domain) as node:
            threads = _spin(node)
            client = node.create_action_client(Rotate, "/turtle1/rotate_absolute")
            assert client.wait_for_server(WAIT)
            feedback: list[float] = []
            handle = client.send_goal_async(Rotate.Goal(theta=2.0),
                                            feedback_callback=lambda m: feedback.append(m.feedback.remaining)
                                            ).result(WAIT)
            assert handle.accepted and (handle.stamp.sec, handle.stamp.nanosec) == (5, 6)
            assert wait_for(lambda: any(d.get("goal") == handle.goal_id_text and d["theta"] == 2.0
                                        for d in lines), WAIT)
            response = handle.get_result_async().result(WAIT)
            assert (response.status, response.result.delta) == (GoalStatus.STATUS_SUCCEEDED, 2.0)
            assert wait_for(lambda: feedback == [2.0, 1.0, 0.0], WAIT), feedback
            assert wait_for(lambda: handle.status == GoalStatus.STATUS_SUCCEEDED, WAIT)
            refused = handle.cancel_goal_async().result(WAIT)
            assert refused.return_code == 1 and refused.goals_canceling == []
            assert wait_for(lambda: any(d.get("cancel") == handle.goal_id_text for d in lines), WAIT)
        for t in threads:
            t.join(timeout=2.0)
    finally:
        kill_process(peer)


def test_a_result_whose_server_is_gone_fails_with_a_reason(router: int) -> None:
    """rmw_zenoh's wire answers a get_result to nobody with a timeout at once: the client asks again only
    while a server is there, and otherwise says the server is gone (no busy loop, no hang)."""
    from zenoh_robot.services import ServiceUnavailable

    domain = fresh_domain()
    release = threading.Event()

    def held(handle: ServerGoalHandle) -> Any:
        release.wait(WAIT)
        handle.succeed()
        return Rotate.Result(delta=1.0)
    with _node("turtlesim", router, domain) as server_node, _node("teleop", router, domain) as client_node:
        threads = _spin(server_node, client_node)
        server = server_node.create_action_server(Rotate, "/turtle1/rotate_absolute", held)
        client = client_node.create_action_client(Rotate, "/turtle1/rotate_absolute", result_poll_s=0.5)
        assert client.wait_for_server(WAIT)
        handle = client.send_goal_async(Rotate.Goal(theta=1.0)).result(WAIT)
        result = handle.get_result_async()
        assert wait_for(lambda: client._result.attempts >= 2, WAIT)      # asked again while the goal runs
        server.destroy()
        with pytest.raises(ServiceUnavailable, match="no server"):
            result.result(WAIT)
        asked = client._result.attempts
        release.set()
        assert not wait_for(lambda: client._result.attempts > asked, 1.0)  # and it stopped asking
    for t in threads:
        t.join(timeout=2.0)


def test_a_ros2_call_that_runs_out_of_time_is_a_timeout(router: int) -> None:
    """What get_result's asking again rests on: Zenoh ends a query that ran out of time with its own
    ``Timeout`` error reply, which is a ServiceTimeout, not the server's ServiceError."""
    from concurrent.futures import Future

    from zenoh_robot.ros2 import ros2_service_type
    from zenoh_robot.services import ServiceTimeout

    domain = fresh_domain()
    srv = ros2_service_type("std_srvs/srv/Trigger")
    never: Future[Any] = Future()
    with _node("slow", router, domain) as node:
        threads = _spin(node)
        node.create_service("/slow", srv.request, srv.response, lambda r: never)
        client = node.create_client("/slow", srv.request, srv.response)
        assert client.wait_for_service(WAIT)
        with pytest.raises(ServiceTimeout):
            client.call(srv.request(), timeout=0.3)
    for t in threads:
        t.join(timeout=2.0)
