"""The ROS 2 wire format (rmw_zenoh's) byte by byte, and two zenoh-robot nodes speaking it over real
Zenoh sessions: keys, CDR payloads, the 33-byte attachment, @ros2_lv tokens, GIDs, QoS strings,
RIHS01 hashes (checked against ROS 2's published hash of std_msgs/msg/String)."""
from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
from typing import Any

import pytest
import xxhash
from conftest import linked_configs, wait_for

from zenoh_robot import Node, QoSProfile
from zenoh_robot.message import message, type_support
from zenoh_robot.msgs import Setpoint
from zenoh_robot.ros2 import cdr_codec, load_ros2_msg, msg_definition, ros2_type, typestore
from zenoh_robot.wire import MalformedSample, ros2_wire
from zenoh_robot.wire.ros2 import (
    dds_type_name,
    decode_ros2_qos,
    encode_ros2_qos,
    pack_attachment,
    parse_any_token,
    ros_type_name,
    token_gid,
    unpack_attachment,
)

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_rihs01_hash_of_std_msgs_string_is_ros2s() -> None:
    String = ros2_type("std_msgs/msg/String")
    assert type_support(String).name == "std_msgs/msg/String"
    assert type_support(String).hash == STRING_HASH
    assert ros2_type("std_msgs/String") is String


# rosidl_generator_c's std_msgs/msg/Char (Kilted, char__description.c: FIELD_TYPE_UINT8 "data"; the
# bytes of std_msgs__msg__Char__get_type_hash). rosbags alone hashes the char as FIELD_TYPE_CHAR and
# gives RIHS01_8914cecc..., which no ROS 2 node would match.
CHAR_HASH = "RIHS01_3ad2d04dd29ba19d04b16659afa3ccaedd691914b02a64e82e252f2fa6a586a9"


def test_char_field_hashes_as_rosidl_uint8() -> None:
    Char = ros2_type("std_msgs/msg/Char")
    assert type_support(Char).hash == CHAR_HASH
    assert type_support(load_ros2_msg("char data", "zr_test/msg/MyChar")).hash != CHAR_HASH   # the name counts
    payload = cdr_codec(Char).serialize(type_support(Char).encode(Char(data=65)))
    assert payload == b"\x00\x01\x00\x00A"


def test_srv_half_definitions_are_named_as_ros2_names_them() -> None:
    """rosbags files a .srv half under pkg/srv/msg/X and its relative types under pkg/srv/msg/T; ROS 2
    says pkg/srv/X and pkg/msg/T (the hash depends on it)."""
    load_ros2_msg("float64 x", "zr_test/msg/Point1")
    Req = load_ros2_msg("Point1 p\ngeometry_msgs/Point q", "zr_test/srv/Go_Request")
    assert type_support(Req).name == "zr_test/srv/Go_Request"
    assert type_support(type(Req().p)).name == "zr_test/msg/Point1"


def test_data_key_and_cdr_payload_bytes() -> None:
    String = ros2_type("std_msgs/msg/String")
    wire = ros2_wire(3)
    ts = type_support(String)
    assert wire.data_key("uav1/chatter", ts) == f"3/uav1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert wire.data_key("chatter", None) == "3/chatter/*/*"
    enc = wire.encoder(ts, 12345)
    # encapsulation 00 01 00 00, uint32 length 6 (with NUL), "hello\0"
    assert enc.pack(1, 0, ts.encode(String(data="hello"))) == bytes.fromhex("00010000") + \
        struct.pack("<I", 6) + b"hello\x00"
    assert dds_type_name("example_interfaces/srv/AddTwoInts") == "example_interfaces::srv::dds_::AddTwoInts_"
    assert ros_type_name("std_msgs::msg::dds_::String_") == "std_msgs/msg/String"


@pytest.mark.parametrize("name", ["geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu", "sensor_msgs/msg/NavSatFix",
                                  "sensor_msgs/msg/CompressedImage", "nav_msgs/msg/Odometry",
                                  "sensor_msgs/msg/JointState", "std_msgs/msg/Empty"])
def test_cdr_round_trip_equals_rosbags_bytes(name: str) -> None:
    T = ros2_type(name)
    ts = type_support(T)
    store = typestore()
    msg = T()
    if name.endswith("CompressedImage"):
        msg = T(format="jpeg", data=b"\xff\xd8abc")
    if name.endswith("JointState"):
        msg = T(name=["a", "b"], position=[1.0, 2.5], velocity=[], effort=[0.0, 0.0])
    payload = cdr_codec(T).serialize(ts.encode(msg))
    assert payload[:4] == b"\x00\x01\x00\x00"
    assert ts.decode(cdr_codec(T).deserialize(payload)) == msg
    # rosbags reads the bytes back to the same values, and writes the same bytes.
    again = bytes(store.serialize_cdr(store.deserialize_cdr(payload, name), name))
    assert again == payload


def test_attachment_is_33_bytes_seq_stamp_16_gid() -> None:
    gid = bytes(range(16))
    data = pack_attachment(7, 1_700_000_000_123_456_789, gid)
    assert data == struct.pack("<q", 7) + struct.pack("<q", 1_700_000_000_123_456_789) + b"\x10" + gid
    assert len(data) == 33
    assert unpack_attachment(data) == (7, 1_700_000_000_123_456_789, gid)
    for bad in (None, b"", data[:32], data + b"\x00", data[:16] + b"\x08" + gid):
        with pytest.raises(MalformedSample):
            unpack_attachment(bad)


def test_gid_is_xxh3_128_of_the_token_low_then_high_little_endian() -> None:
    token = "@ros2_lv/0/aaa/1/2/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/" + STRING_HASH + "/1:2:1,10:,:,:,,"
    h = xxhash.xxh3_128_intdigest(token.encode())
    low, high = h & (2**64 - 1), h >> 64
    assert token_gid(token) == struct.pack("<QQ", low, high)


def test_qos_string_is_explicit_and_reads_both_forms() -> None:
    q = QoSProfile(depth=5, reliability="best_effort", durability="transient_local", deadline=0.1,
                   liveliness="manual_by_topic", liveliness_lease_duration=1.5)
    text = encode_ros2_qos(q)
    assert text == "2:1:1,5:0,100000000:9223372036,854775807:3,1,500000000"
    back = decode_ros2_qos(text)
    assert (back.reliability, back.durability, back.depth, back.deadline, back.lifespan, back.liveliness,
            back.liveliness_lease_duration) == (q.reliability, q.durability, 5, 0.1, None, q.liveliness, 1.5)
    assert encode_ros2_qos(QoSProfile()) == \
        "1:2:1,10:9223372036,854775807:9223372036,854775807:1,9223372036,854775807"
    # The elided form of older rmw_zenoh (defaults left empty) still reads.
    old = decode_ros2_qos("::,7:,:,:,,")
    assert (old.reliability.name, old.durability.name, old.depth, old.deadline) == ("RELIABLE", "VOLATILE", 7, None)


def test_a_type_without_a_ros2_definition_is_refused_in_one_line(ns: str) -> None:
    listen, _ = linked_configs()
    with Node("n", namespace=ns, config=listen, wire=ros2_wire(5)) as node:
        with pytest.raises(TypeError, match=r"^zenoh_robot/Setpoint has no ROS 2 definition: .*ros2_type"):
            node.create_publisher(Setpoint, "sp", 10)
        with pytest.raises(TypeError, match="no ROS 2 definition"):
            node.create_subscription(Setpoint, "sp", lambda m: None, 10)


def test_load_ros2_msg_without_a_build_step() -> None:
    T = load_ros2_msg("float64 x\nstd_msgs/Header header\nuint8[] blob\nint32 MODE=3\n", "zr_test_msgs/msg/Probe")
    ts = type_support(T)
    assert ts.name == "zr_test_msgs/msg/Probe" and ts.hash.startswith("RIHS01_") and T.MODE == 3
    msg = T(x=2.5, blob=b"\x01\x02")
    assert ts.decode(cdr_codec(T).deserialize(cdr_codec(T).serialize(ts.encode(msg)))) == msg
    assert "std_msgs/Header header" in msg_definition("zr_test_msgs/msg/Probe")


@pytest.fixture
def ros2_pair(ns: str):
    listen, connect = linked_configs()
    wire = ros2_wire(9)
    with Node("listener", namespace=ns, config=listen, wire=wire) as b, \
            Node("talker", namespace=ns, config=connect, wire=wire) as a:
        assert wait_for(lambda: any(link.zid == b.session.zid() for link in a.session.info.links()), 10.0)
        yield a, b


def test_two_nodes_on_the_ros2_wire_exact_bytes_on_zenoh(ros2_pair, ns: str) -> None:
    a, b = ros2_pair
    String = ros2_type("std_msgs/msg/String")
    raw: list[tuple[str, bytes, bytes]] = []
    b.session.declare_subscriber("9/**", lambda s: raw.append((str(s.key_expr), s.payload.to_bytes(),
                                                               s.attachment.to_bytes())))
    got: list[Any] = []
    sub = b.create_subscription(String, "chatter", lambda m, i: got.append((m, i)), 10)
    pub = a.create_publisher(String, "chatter", 10)
    assert wait_for(lambda: pub.get_subscription_count() == 1 and sub.get_publisher_count() == 1)
    sent = [pub.publish(String(data=f"hi {i}")) for i in range(3)]
    assert b.spin_until(lambda: len(got) == 3, timeout=5.0) and wait_for(lambda: len(raw) == 3)
    assert [m.data for m, _ in got] == ["hi 0", "hi 1", "hi 2"]
    # Our own publisher id comes back (the token's entity id), heartbeats and samples agree.
    assert {i.publisher_id for _, i in got} == {pub.publisher_id}
    key, payload, attachment = raw[0]
    assert key == f"9/{ns}/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert payload == b"\x00\x01\x00\x00" + struct.pack("<I", 5) + b"hi 0\x00"
    tokens = [str(r.ok.key_expr) for r in a.session.liveliness().get("@ros2_lv/9/**", timeout=1.0) if r.ok]
    [mp] = [t for t in tokens if "/MP/" in t]
    assert unpack_attachment(attachment) == (sent[0].seq, sent[0].stamp_ns, token_gid(mp))
    tok = parse_any_token(mp)
    assert (tok.kind, tok.domain_id, tok.zid, tok.namespace, tok.node, tok.name, tok.type_name, tok.type_hash) == \
        ("MP", 9, str(a.session.info.zid()), f"/{ns}", "talker", f"/{ns}/chatter", "std_msgs/msg/String",
         STRING_HASH)
    assert mp.split("/")[6:10] == ["%", f"%{ns}", "talker", f"%{ns}%chatter"]
    [nn] = [t for t in tokens if "/NN/" in t and t.endswith("/talker")]
    assert nn.split("/")[3] == nn.split("/")[4] == mp.split("/")[3]     # nid == eid of a node; endpoints name it
    assert sub.counters.malformed == 0


def test_deadline_and_liveliness_events_fire_on_the_ros2_wire(ros2_pair) -> None:
    a, b = ros2_pair
    String = ros2_type("std_msgs/msg/String")
    qos = QoSProfile(depth=10, deadline=0.1, liveliness="manual_by_topic", liveliness_lease_duration=0.3)
    missed: list[Any] = []
    changed: list[Any] = []
    from zenoh_robot import SubscriptionEventCallbacks
    sub = b.create_subscription(String, "beat", lambda m: None, qos, event_callbacks=SubscriptionEventCallbacks(
        deadline=missed.append, liveliness=changed.append))
    pub = a.create_publisher(String, "beat", qos)
    assert wait_for(lambda: pub.get_subscription_count() == 1 and sub.get_publisher_count() == 1)
    pub.publish(String(data="x"))
    assert b.spin_until(lambda: bool(missed) and any(c.alive_count == 0 for c in changed), timeout=5.0), \
        (missed, changed)
    assert any(c.alive_count == 1 for c in changed)      # alive once, then lost after the lease


def test_ros2_and_envelope_nodes_do_not_see_each_other(ns: str) -> None:
    listen, connect = linked_configs()
    String = ros2_type("std_msgs/msg/String")
    with Node("env", namespace=ns, config=listen) as env_node, \
            Node("ros", namespace=ns, config=connect, wire=ros2_wire(4)) as ros_node:
        ros_node.create_publisher(String, "t", 10)
        time.sleep(0.5)
        assert env_node.get_publishers_info_by_topic("t") == []
        assert "ros" not in env_node.get_node_names()


def test_a_malformed_cdr_or_attachment_is_counted_not_delivered(ros2_pair) -> None:
    a, b = ros2_pair
    String = ros2_type("std_msgs/msg/String")
    sub = b.create_subscription(String, "bad", lambda m: None, 10)
    time.sleep(0.3)
    good = pack_attachment(1, time.time_ns(), bytes(16))
    a.session.put(sub.data_key, b"\x00\x01\x00\x00\xff\xff\xff\x7f", attachment=good)   # string length past the end
    a.session.put(sub.data_key, b"\x00\x01\x00\x00\x01\x00\x00\x00\x00")                # no attachment
    assert b.spin_until(lambda: sub.counters.malformed == 2, timeout=5.0)
    assert sub.counters.delivered == 0


def test_import_zenoh_robot_loads_neither_rosbags_nor_xxhash() -> None:
    code = "import json, sys; import zenoh_robot, zenoh_robot.wire; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    loaded = json.loads(out.stdout)
    assert "zenoh_robot.wire.ros2" in loaded
    assert [m for m in loaded if m.split(".")[0] in ("rosbags", "xxhash", "zenoh_ros2_sdk")
            or m.startswith("zenoh_robot.ros2")] == []


def test_envelope_message_classes_are_unchanged() -> None:
    @message(name="zr_test/Plain")
    class Plain(ros2_type("std_msgs/msg/String").__mro__[1]):    # Message
        x: float = 0.0
    assert not type_support(Plain).hash.startswith("RIHS01_")
