"""`zenoh-robot bag record --ros2` writes ROS 2 topics as rosbag2 does: a `cdr` channel whose schema is
the type's full `ros2msg` definition. A real recorder process records a ROS 2 node's PoseStamped and
Imu over real Zenoh sessions; the file is read back with the mcap reader, and each message decoded by
rosbags from the schema in the file alone (a fresh, empty typestore), as Foxglove and `ros2 bag` do.
"""
from __future__ import annotations

from pathlib import Path

from conftest import fresh_domain, record_ros2_talker
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def test_bag_record_writes_ros2_cdr_channels_that_rosbags_decodes(tmp_path: Path) -> None:
    domain = fresh_domain()
    out = tmp_path / "ros2.mcap"
    r = record_ros2_talker(out, domain, 4)
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
