"""`zenoh-robot foxglove --ros2`: ROS 2 topics reach Foxglove as `cdr` channels with their `ros2msg` schema,
so Foxglove decodes them natively (a PoseStamped of the companion's kind, PX4's /fmu/out/vehicle_status).

Real parts: a ROS 2 wire Node on a loopback socket, the bridge as its own process, a WebSocket client
speaking the Foxglove protocol; each message is decoded by rosbags from the schema the bridge advertised,
alone (an empty typestore), as Foxglove does.
"""
from __future__ import annotations

import asyncio
import threading
from typing import Any

from conftest import free_port, fresh_domain, python_proc, stop_process
from foxglove_client import watch
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from zenoh_robot import Node, QoSProfile, SessionConfig
from zenoh_robot.ros2 import ros2_type
from zenoh_robot.wire import ros2_wire

POSE, STATUS = "geometry_msgs/msg/PoseStamped", "px4_msgs/msg/VehicleStatus"
TOPICS = {"/zr/pose": POSE, "/fmu/out/vehicle_status": STATUS}


def _talk(node: Node, stop: threading.Event) -> None:
    T = {n: ros2_type(n) for n in (POSE, STATUS, "std_msgs/msg/Header", "builtin_interfaces/msg/Time",
                                   "geometry_msgs/msg/Pose", "geometry_msgs/msg/Point")}
    pose = node.create_publisher(T[POSE], "pose", QoSProfile(depth=10))
    status = node.create_publisher(T[STATUS], "/fmu/out/vehicle_status", QoSProfile(depth=10))
    i = 0
    while not stop.wait(0.05):
        pose.publish(T[POSE](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=i),
                                                             frame_id="map"),
                             pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=1.5, y=-2.0))))
        status.publish(T[STATUS](timestamp=1000 + i, arming_state=2, nav_state=14))
        i += 1


def _decode(channel: dict[str, Any], payload: bytes) -> Any:
    store = get_typestore(Stores.EMPTY)     # only what the bridge said: its schema text
    store.register(get_types_from_msg(channel["schema"], channel["schemaName"]))
    return store.deserialize_cdr(payload, channel["schemaName"])


def test_bridge_shows_ros2_topics_as_cdr_channels_with_ros2msg_schemas() -> None:
    domain = fresh_domain()
    port, ws_port = free_port(), free_port()
    config = SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, shared_memory=False)
    stop = threading.Event()
    with Node("companion", namespace="zr", config=config, wire=ros2_wire(domain)) as node:
        talker = threading.Thread(target=_talk, args=(node, stop), daemon=True)
        talker.start()
        bridge = python_proc("-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())",
                             "foxglove", "--ros-domain-id", str(domain), "-e", f"tcp/127.0.0.1:{port}",
                             "-l", "tcp/127.0.0.1:0", "--port", str(ws_port))
        try:
            assert bridge.stdout is not None
            lines: list[str] = []
            while not any(f"ws://127.0.0.1:{ws_port}" in x for x in lines) and bridge.poll() is None:
                lines.append(bridge.stdout.readline())
            assert bridge.poll() is None, "".join(lines)
            threading.Thread(target=lambda: lines.extend(bridge.stdout or []), daemon=True).start()
            channels, got = asyncio.run(watch(ws_port, 20.0, lambda channels, got: len(got) == len(TOPICS),
                                              subscribe=lambda ch: [t for t in TOPICS if t in ch]))
        finally:
            stop.set()
            talker.join()
            out = stop_process(bridge)
    for topic, type_name in TOPICS.items():
        assert topic in channels, f"advertised: {sorted(channels)}"
        ch = channels[topic]
        assert (ch["encoding"], ch["schemaName"], ch["schemaEncoding"]) == ("cdr", type_name, "ros2msg"), ch
        assert topic in got, (topic, sorted(got), "".join(lines))
    assert "MSG: geometry_msgs/Pose" in channels["/zr/pose"]["schema"]    # the full definition, rosbag2's shape
    pose = _decode(channels["/zr/pose"], got["/zr/pose"])
    assert (pose.header.frame_id, pose.pose.position.x, pose.pose.position.y) == ("map", 1.5, -2.0)
    status = _decode(channels["/fmu/out/vehicle_status"], got["/fmu/out/vehicle_status"])
    assert (status.arming_state, status.nav_state) == (2, 14) and status.timestamp >= 1000
    assert bridge.returncode == 0, out
