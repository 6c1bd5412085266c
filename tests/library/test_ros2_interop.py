"""A zenoh-robot node on the ROS 2 wire against an independent implementation of rmw_zenoh's
format, zenoh-ros2-sdk (PyPI), in a real child process over real Zenoh sessions: pub/sub both
ways of std_msgs/String, geometry_msgs/PoseStamped and sensor_msgs/Imu, and each side's graph
listing the other's node and topics with the right types and QoS.

The peer loads .msg files from a directory (it would fetch them from git otherwise): we write
them from rosbags' definitions (``msg_definition``); it computes the RIHS01 hashes itself, and
the data keys only meet if its hashes equal ours.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from conftest import free_port, fresh_domain, kill_process, wait_for
from ros2_peer import PEER_PRELUDE, start_peer, write_msgs

from zenoh_robot import Node, QoSProfile, SessionConfig
from zenoh_robot.message import type_support
from zenoh_robot.ros2 import ros2_type
from zenoh_robot.wire import ros2_wire

TYPES = ["std_msgs/msg/String", "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu"]

PEER = PEER_PRELUDE + r"""
from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber
from zenoh_ros2_sdk import discovery

def on(topic):
    def cb(msg):
        if topic == "string":
            out(got=topic, data=msg.data)
        elif topic == "pose":
            p = msg.pose.position
            out(got=topic, frame=msg.header.frame_id, sec=msg.header.stamp.sec, xyz=[p.x, p.y, p.z],
                w=msg.pose.orientation.w)
        else:
            out(got=topic, frame=msg.header.frame_id, cov=[float(v) for v in msg.orientation_covariance],
                gyro=[msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z])
    return cb

subs = [ROS2Subscriber(f"/zr/{t}", ty, on(t), node_name="sdk_listener", **common)
        for t, ty in (("string", "std_msgs/msg/String"), ("pose", "geometry_msgs/msg/PoseStamped"),
                      ("imu", "sensor_msgs/msg/Imu"))]
pubs = {t: ROS2Publisher(f"/sdk/{t}", ty, node_name="sdk_talker", **common)
        for t, ty in (("string", "std_msgs/msg/String"), ("pose", "geometry_msgs/msg/PoseStamped"),
                      ("imu", "sensor_msgs/msg/Imu"))}
T = pubs["pose"].session_mgr.store.types
out(ready=True)
for line in sys.stdin:
    cmd = line.strip()
    if cmd == "graph":
        out(graph=[[n, list(ts)] for n, ts in discovery.get_topic_names_and_types(
            domain_id=domain, router_ip="127.0.0.1", router_port=port, timeout=1.0)])
        info = discovery.get_topic_info("/zr/pose", domain_id=domain, router_ip="127.0.0.1", router_port=port,
                                        timeout=1.0, verbose=True)
        out(info=[[e.node_name, e.node_namespace, e.topic_type, e.type_hash, e.qos] for e in info.subscribers]
            if info else None)
    elif cmd == "publish":
        stamp = T["builtin_interfaces/msg/Time"](sec=7, nanosec=8)
        header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="map")
        pubs["string"].publish(data="from sdk")
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=-3.5),
                                           orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        pubs["pose"].publish(header=header, pose=pose)
        import numpy as np
        vec = T["geometry_msgs/msg/Vector3"]
        pubs["imu"].publish(header=header, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                            orientation_covariance=np.arange(9, dtype=np.float64),
                            angular_velocity=vec(x=0.1, y=0.2, z=0.3), angular_velocity_covariance=np.zeros(9),
                            linear_acceleration=vec(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))
        out(published=True)
    elif cmd == "quit":
        break
"""


@pytest.fixture
def pair(tmp_path: Path):
    """(our node on the ROS 2 wire, the zenoh-ros2-sdk peer) on a domain of their own."""
    msgs = write_msgs(tmp_path / "msgs", TYPES)
    port = free_port()
    domain = fresh_domain()
    config = SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, shared_memory=False)
    with Node("zr_node", namespace="zr", config=config, wire=ros2_wire(domain)) as node:
        peer = start_peer(PEER, str(msgs), str(port), str(domain))
        proc = peer.proc
        try:
            assert wait_for(lambda: peer.find("ready"), 30.0), "".join(peer.raw)[-3000:]
            yield node, peer
        finally:
            # Nothing is asserted of the peer's exit, and zenoh-ros2-sdk's threads keep it alive after "quit"
            # (every teardown waited the whole 10 s for it): end it at once.
            kill_process(proc)


def test_the_peer_hears_our_string_pose_and_imu(pair) -> None:
    node, peer = pair
    String, PoseStamped, Imu = (ros2_type(t) for t in TYPES)
    pubs = {"string": node.create_publisher(String, "string", 10),
            "pose": node.create_publisher(PoseStamped, "pose", 10),
            "imu": node.create_publisher(Imu, "imu", QoSProfile(depth=5))}   # the peer asks RELIABLE
    assert wait_for(lambda: all(p.get_subscription_count() == 1 for p in pubs.values()), 15.0), \
        [(t, p.get_subscription_count()) for t, p in pubs.items()]
    pose = PoseStamped()
    pose.header.frame_id = "map"
    pose.header.stamp.sec = 42
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 1.5, -2.0, 10.0
    pose.pose.orientation.w = 1.0
    imu = Imu()
    imu.header.frame_id = "imu_link"
    imu.orientation_covariance = [float(i) for i in range(9)]
    imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = 0.5, -0.25, 1.0
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline and not all(peer.find("got", t) for t in ("string", "pose", "imu")):
        pubs["string"].publish(String(data="hello ros"))
        pubs["pose"].publish(pose)
        pubs["imu"].publish(imu)
        time.sleep(0.2)
    assert peer.find("got", "string")[0]["data"] == "hello ros", "".join(peer.raw)[-3000:]
    got = peer.find("got", "pose")[0]
    assert (got["frame"], got["sec"], got["xyz"], got["w"]) == ("map", 42, [1.5, -2.0, 10.0], 1.0)
    got = peer.find("got", "imu")[0]
    assert (got["frame"], got["cov"], got["gyro"]) == ("imu_link", [float(i) for i in range(9)], [0.5, -0.25, 1.0])


def test_we_hear_the_peers_string_pose_and_imu(pair) -> None:
    node, peer = pair
    String, PoseStamped, Imu = (ros2_type(t) for t in TYPES)
    got: dict[str, list[Any]] = {"string": [], "pose": [], "imu": []}
    subs = [node.create_subscription(String, "/sdk/string", lambda m, i: got["string"].append((m, i)), 10),
            node.create_subscription(PoseStamped, "/sdk/pose", lambda m: got["pose"].append(m), 10),
            node.create_subscription(Imu, "/sdk/imu", lambda m: got["imu"].append(m), 10)]
    assert wait_for(lambda: all(s.get_publisher_count() == 1 for s in subs), 15.0)
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline and not all(got.values()):
        peer.send("publish")
        node.spin_until(lambda: all(got.values()), timeout=0.3)
    assert all(got.values()), (got, [s.counters for s in subs])
    msg, info = got["string"][0]
    assert msg == String(data="from sdk") and info.type_name == "std_msgs/msg/String"
    pose = got["pose"][0]
    assert (pose.header.frame_id, pose.header.stamp.sec, pose.header.stamp.nanosec) == ("map", 7, 8)
    assert (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z, pose.pose.orientation.w) == \
        (1.0, 2.0, -3.5, 1.0)
    imu = got["imu"][0]
    assert imu.orientation_covariance == [float(i) for i in range(9)]
    assert (imu.angular_velocity.x, imu.linear_acceleration.z) == (0.1, 9.81)
    assert all(s.counters.malformed == 0 and s.counters.type_mismatch == 0 for s in subs)


def test_each_graph_lists_the_other(pair) -> None:
    node, peer = pair
    PoseStamped = ros2_type("geometry_msgs/msg/PoseStamped")
    node.create_subscription(PoseStamped, "pose", lambda m: None, QoSProfile(depth=7, reliability="best_effort"))
    # Ours lists the peer's nodes and topics with ROS types.
    assert wait_for(lambda: {("sdk_talker", "/sdk"), ("sdk_listener", "/sdk")}
                    <= set(node.get_node_names_and_namespaces()), 15.0), node.get_node_names_and_namespaces()
    topics = dict(node.get_topic_names_and_types())
    assert topics["/sdk/pose"] == ["geometry_msgs/msg/PoseStamped"]
    assert topics["/sdk/imu"] == ["sensor_msgs/msg/Imu"]
    assert topics["/zr/string"] == ["std_msgs/msg/String"]       # the peer's subscription
    [info] = node.get_publishers_info_by_topic("/sdk/pose")
    assert (info.node_name, info.node_namespace, info.topic_type, info.topic_type_hash) == \
        ("sdk_talker", "/sdk", "geometry_msgs/msg/PoseStamped", type_support(PoseStamped).hash)
    assert info.qos_profile.reliability.name == "RELIABLE" and info.qos_profile.depth == 10
    # The peer lists ours. Its listing is one query of at most 1 s: ask again (as a user would) until it
    # holds our subscription, at most 15 s.
    def listed() -> bool:
        infos = peer.find("info")
        return bool(infos) and any(e[0] == "zr_node" for e in infos[-1]["info"] or [])
    deadline = time.monotonic() + 15.0
    while not listed() and time.monotonic() < deadline:
        asked = len(peer.find("info"))
        peer.send("graph")
        wait_for(lambda n=asked: len(peer.find("info")) > n, 5.0)
    assert listed(), "".join(peer.raw)[-3000:]
    graph = dict((n, ts) for n, ts in peer.find("graph")[-1]["graph"])
    assert graph["/zr/pose"] == ["geometry_msgs/msg/PoseStamped"]
    # /zr/pose has the peer's own subscription too, listed in no fixed order: ours is the one of zr_node.
    [ours] = [e for e in peer.find("info")[-1]["info"] if e[0] == "zr_node"]
    assert ours[:4] == ["zr_node", "/zr", "geometry_msgs/msg/PoseStamped", type_support(PoseStamped).hash]
    assert ours[4].startswith("2:2:1,7:")     # best effort, volatile, keep last 7
