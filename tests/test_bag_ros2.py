"""`zenoh-robot bag record --ros2` writes ROS 2 topics as rosbag2 does: a `cdr` channel whose schema is
the type's full `ros2msg` definition. A real recorder process records a ROS 2 node's PoseStamped and
Imu over real Zenoh sessions; the file is read back with the mcap reader, and each message decoded by
rosbags from the schema in the file alone (a fresh, empty typestore), as Foxglove and `ros2 bag` do.
"""
from __future__ import annotations

import secrets
import subprocess
import sys
import threading
from pathlib import Path

from conftest import ROOT, free_port
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from zenoh_robot import Node, QoSProfile, SessionConfig
from zenoh_robot.ros2 import ros2_type
from zenoh_robot.wire import ros2_wire

CLI = [sys.executable, "-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())"]


def test_bag_record_writes_ros2_cdr_channels_that_rosbags_decodes(tmp_path: Path) -> None:
    domain = 100 + secrets.randbelow(100)
    port = free_port()
    out = tmp_path / "ros2.mcap"
    T = {n: ros2_type(n) for n in ("geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu", "std_msgs/msg/Header",
                                   "builtin_interfaces/msg/Time", "geometry_msgs/msg/Pose",
                                   "geometry_msgs/msg/Point", "geometry_msgs/msg/Vector3")}
    config = SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, shared_memory=False)
    with Node("talker", namespace="zr", config=config, wire=ros2_wire(domain)) as node:
        pose_pub = node.create_publisher(T["geometry_msgs/msg/PoseStamped"], "pose", QoSProfile(depth=10))
        imu_pub = node.create_publisher(T["sensor_msgs/msg/Imu"], "imu", QoSProfile(depth=10))
        stop = threading.Event()

        def talk() -> None:
            i = 0
            while not stop.wait(0.02):
                header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=100 + i, nanosec=7),
                                                  frame_id="map")
                point = T["geometry_msgs/msg/Point"](x=float(i), y=2.0, z=-3.5)
                pose_pub.publish(T["geometry_msgs/msg/PoseStamped"](
                    header=header, pose=T["geometry_msgs/msg/Pose"](position=point)))
                imu_pub.publish(T["sensor_msgs/msg/Imu"](
                    header=header, linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.81)))
                i += 1

        talker = threading.Thread(target=talk, daemon=True)
        talker.start()
        try:
            r = subprocess.run([*CLI, "bag", "record", "-a", "-o", str(out),
                                "--duration", "4", "--ros-domain-id", str(domain), "-e", f"tcp/127.0.0.1:{port}",
                                "-l", "tcp/127.0.0.1:0"],
                               cwd=ROOT, capture_output=True, text=True, timeout=60)
        finally:
            stop.set()
            talker.join(timeout=2.0)
    assert r.returncode == 0, r.stderr

    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        for topic, type_name in (("/zr/pose", "geometry_msgs/msg/PoseStamped"), ("/zr/imu", "sensor_msgs/msg/Imu")):
            ch = channels[topic]
            schema = summary.schemas[ch.schema_id]
            assert (ch.message_encoding, schema.encoding, schema.name) == ("cdr", "ros2msg", type_name), r.stderr
        decoded: dict[str, list[object]] = {"/zr/pose": [], "/zr/imu": []}
        for schema, channel, message in reader.iter_messages():
            if channel.topic not in decoded:
                continue
            # Only what the file says: the schema text registers every type the message needs.
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(schema.data.decode(), schema.name))
            decoded[channel.topic].append(store.deserialize_cdr(message.data, schema.name))
    poses, imus = decoded["/zr/pose"], decoded["/zr/imu"]
    assert len(poses) > 20 and len(imus) > 20, (len(poses), len(imus), r.stderr)
    p = poses[-1]
    assert p.header.frame_id == "map" and p.header.stamp.nanosec == 7                         # type: ignore[attr-defined]
    assert (p.pose.position.y, p.pose.position.z) == (2.0, -3.5)                             # type: ignore[attr-defined]
    xs = [q.pose.position.x for q in poses]                                                  # type: ignore[attr-defined]
    assert xs == sorted(xs) and len(set(xs)) == len(xs), "each sample once, in order"
    assert imus[-1].linear_acceleration.z == 9.81                                            # type: ignore[attr-defined]
