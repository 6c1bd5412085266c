"""The generated CDR fast path (zenoh_robot/ros2/fastcdr.py) against rosbags, the reference: the same
bytes for every body, the same values for every payload, the same refusals for bytes that are not
the type's CDR (hypothesis over the standard types the drone publishes, a px4_msgs-like flat struct
and a type made to hit every alignment case); PX4's trailing bytes cut on request; and two nodes on
the ROS 2 wire putting exactly rosbags' bytes on a real Zenoh session."""
from __future__ import annotations

import struct
from typing import Any

import pytest
from conftest import linked_configs, wait_for
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from zenoh_robot import Node
from zenoh_robot.message import type_support
from zenoh_robot.ros2 import cdr_codec, load_ros2_msg, ros2_type, typestore
from zenoh_robot.ros2.fastcdr import build
from zenoh_robot.ros2.types import register_definitions
from zenoh_robot.wire import ros2_wire

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

# A uORB-style fixed-size struct, as PX4's zenoh module sends it (px4_msgs/VehicleAttitude's shape).
PX4_LIKE = "zr_fastcdr/msg/Px4Like"
PX4_LIKE_MSG = ("uint64 timestamp\nuint64 timestamp_sample\nfloat32[4] q\nfloat32[4] delta_q_reset\n"
                "uint8 quat_reset_counter\nbool armed\nint16 temp\nfloat64 alt\nuint8[3] flags\n")
# Every alignment case the generator resolves: a run broken by a string, 8-byte values after odd
# offsets, empty and non-empty sequences of 1-, 2-, 8-byte elements, strings in sequences and
# fixed arrays, nested types alone, in fixed arrays and in sequences, byte and char scalars.
MIXED = "zr_fastcdr/msg/Mixed"
MIXED_MSG = ("uint8 a\nstring name\nfloat64 x\nbool[] flags\nint8 small\nfloat64[] values\nint16[] shorts\n"
             "byte b\nchar c\nstring[] names\nstring[2] pair\ngeometry_msgs/Point[2] points\n"
             "builtin_interfaces/Time[] stamps\nuint8[] blob\nint64 last\n")
TYPES = ["std_msgs/msg/String", "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu",
         "sensor_msgs/msg/CompressedImage", "nav_msgs/msg/Odometry", PX4_LIKE, MIXED]

load_ros2_msg(PX4_LIKE_MSG, PX4_LIKE)
load_ros2_msg(MIXED_MSG, MIXED)

# byte: rosbags packs a byte scalar as int8 and the schema checks 0..255: 0..127 is what both take.
_INTS = {"int8": (-(1 << 7), (1 << 7) - 1), "uint8": (0, 255), "byte": (0, 127), "char": (0, 255),
         "int16": (-(1 << 15), (1 << 15) - 1), "uint16": (0, (1 << 16) - 1), "int32": (-(1 << 31), (1 << 31) - 1),
         "uint32": (0, (1 << 32) - 1), "int64": (-(1 << 63), (1 << 63) - 1), "uint64": (0, (1 << 64) - 1)}


def _scalar(base: str) -> st.SearchStrategy[Any]:
    if base == "bool":
        return st.booleans()
    if base == "float32":
        return st.floats(width=32, allow_nan=False)
    if base == "float64":
        return st.floats(allow_nan=False)
    if base == "string":
        return st.text(max_size=12)
    low, high = _INTS[base]
    return st.integers(low, high)


def _field(desc: tuple[Any, Any]) -> st.SearchStrategy[Any]:
    node, arg = desc
    if node.name == "BASE":
        return _scalar(arg[0])
    if node.name == "NAME":
        return _body(arg)
    (sub_node, sub_arg), size = arg
    fixed = node.name == "ARRAY"
    if sub_node.name == "BASE" and sub_arg[0] in ("uint8", "byte", "char"):
        return st.binary(min_size=size, max_size=size) if fixed else st.binary(max_size=40)
    elem = _scalar(sub_arg[0]) if sub_node.name == "BASE" else _body(sub_arg)
    return st.lists(elem, min_size=size, max_size=size) if fixed else st.lists(elem, max_size=4)


def _body(name: str) -> st.SearchStrategy[list[Any]]:
    return st.tuples(*[_field(desc) for _f, desc in typestore().fielddefs[name][1]]).map(list)


def _codec(name: str) -> Any:
    codec = cdr_codec(ros2_type(name))
    assert codec.fast is not None, f"{name} has no fast codec"
    return codec


def _same_outcome(fn_a: Any, fn_b: Any) -> Any:
    """Both raise, or both return the same value (returned). Same by repr where == cannot say: a flipped
    bit can make a float NaN, which both decoders read as NaN, and NaN != NaN (seen in a full pass)."""
    try:
        a = fn_a()
    except Exception:
        with pytest.raises(Exception):
            fn_b()
        return None
    b = fn_b()
    assert b == a or repr(b) == repr(a)
    return a


@pytest.mark.parametrize("name", TYPES)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bytes_and_values_are_rosbags(name: str, data: st.DataObject) -> None:
    codec = _codec(name)
    ts = type_support(ros2_type(name))
    body = data.draw(_body(name))
    payload = codec.fast.encode(body)
    assert payload == codec.serialize_rosbags(body)
    assert codec.serialize(body) == payload
    decoded = codec.fast.decode(payload, False)
    assert decoded == codec.deserialize_rosbags(payload)
    assert ts.decode(decoded) == ts.decode(body)


@pytest.mark.parametrize("name", TYPES)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_foreign_bytes_are_refused_or_read_as_rosbags_reads_them(name: str, data: st.DataObject) -> None:
    """Truncated, extended and bit-flipped payloads: the fast decoder accepts exactly what rosbags
    accepts, with the same values (the codec then never needs rosbags but for the error text)."""
    codec = _codec(name)
    payload = bytearray(codec.fast.encode(data.draw(_body(name))))
    cut = data.draw(st.integers(0, len(payload)))
    tail = data.draw(st.binary(max_size=8))
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(payload) - 1), st.integers(0, 255)), max_size=3))
    for index, value in flips:
        payload[index] = value
    candidate = bytes(payload[:cut]) + tail
    _same_outcome(lambda: codec.fast.decode(candidate, False), lambda: codec.deserialize_rosbags(candidate))
    _same_outcome(lambda: codec.deserialize(candidate), lambda: codec.deserialize_rosbags(candidate))


def test_every_truncation_of_a_payload_is_refused() -> None:
    codec = _codec(MIXED)
    ts = type_support(ros2_type(MIXED))
    msg = ros2_type(MIXED)(name="n", values=[1.0], names=["a", ""], blob=b"xyz", flags=[True])
    payload = codec.serialize(ts.encode(msg))
    for cut in range(len(payload)):
        with pytest.raises(Exception):
            codec.fast.decode(payload[:cut], False)
        with pytest.raises(Exception):
            codec.deserialize(payload[:cut])


@pytest.mark.parametrize("extra", range(32))
def test_px4_trailing_bytes_are_cut_on_request(extra: int) -> None:
    """PX4's zenoh module sends the uORB struct's tail (0-31 bytes) after the CDR body; rosbags, and
    so the default, refuses more than the 3 bytes of alignment padding."""
    T = ros2_type(PX4_LIKE)
    ts, codec = type_support(T), _codec(PX4_LIKE)
    msg = T(timestamp=1_588_000, timestamp_sample=1_587_990, q=[1.0, -0.5, 0.25, 0.0], delta_q_reset=[1.0, 0, 0, 0],
            quat_reset_counter=3, armed=True, temp=-40, alt=488.25, flags=b"\x01\x02\x03")
    body = codec.serialize(ts.encode(msg))
    assert len(body) == 4 + 8 + 8 + 16 + 16 + 1 + 1 + 2 + 4 + 8 + 3     # the one alignment gap before alt
    payload = body + bytes(range(0xA0, 0xA0 + extra))
    assert ts.decode(codec.deserialize(payload, cut_trailing=True)) == msg
    assert ts.decode(codec.deserialize_rosbags(payload, cut_trailing=True)) == msg
    if extra <= 3:
        assert ts.decode(codec.deserialize(payload)) == msg
    else:
        with pytest.raises(Exception, match="size mismatch"):    # rosbags' own refusal, through the fallback
            codec.deserialize(payload)


def test_a_type_the_generator_does_not_cover_keeps_rosbags() -> None:
    """A wstring (no .msg of the standard packages has one; IDL can; rosbags' RIHS01 cannot hash it yet,
    so no class is made of it today) is left to rosbags."""
    node, _ = typestore().fielddefs["std_msgs/msg/String"][1][0][1]
    register_definitions({"zr_fastcdr/msg/Wide": ([], [("w", (node, ("wstring", 0))), ("x", (node, ("uint8", 0)))])})
    assert build(typestore(), "zr_fastcdr/msg/Wide") is None
    assert build(typestore(), "std_msgs/msg/String") is not None


def test_a_body_the_fast_path_refuses_gets_rosbags_result() -> None:
    """Whatever the generated code raises on goes to rosbags, which either packs it its own way (here a
    float in an int32 sequence, which numpy truncates) or raises its own error."""
    codec = _codec("std_msgs/msg/Int32MultiArray")
    body = [[[], 0], [1.9, 2]]
    with pytest.raises(TypeError):
        codec.fast.encode(body)
    assert codec.serialize(body) == codec.serialize_rosbags(body)
    with pytest.raises(Exception):
        codec.serialize([[[], 0], ["x"]])


def test_nodes_on_the_ros2_wire_put_rosbags_bytes_on_zenoh(ns: str) -> None:
    listen, connect = linked_configs()
    Imu = ros2_type("sensor_msgs/msg/Imu")
    ts, codec = type_support(Imu), _codec("sensor_msgs/msg/Imu")
    wire = ros2_wire(11)
    with Node("imu_sub", namespace=ns, config=listen, wire=wire) as b, \
            Node("imu_pub", namespace=ns, config=connect, wire=wire) as a:
        seen: list[bytes] = []
        got: list[Any] = []
        sub = b.create_subscription(Imu, "imu", got.append, 10)
        b.session.declare_subscriber(sub.data_key, lambda s: seen.append(s.payload.to_bytes()))
        pub = a.create_publisher(Imu, "imu", 10)
        assert wait_for(lambda: pub.get_subscription_count() == 1 and sub.get_publisher_count() == 1)
        msgs = [Imu(orientation_covariance=[float(i)] * 9) for i in range(3)]
        for i, m in enumerate(msgs):
            m.header.frame_id = "imu" * i
            m.linear_acceleration.z = 9.81 + i
            pub.publish(m)
        assert b.spin_until(lambda: len(got) == 3, timeout=5.0) and wait_for(lambda: len(seen) == 3)
        assert got == msgs and sub.counters.malformed == 0
        assert seen == [codec.serialize_rosbags(ts.encode(m)) for m in msgs]
        assert struct.unpack_from("<I", seen[1], 12)[0] == 4      # "imu" and its NUL after the stamp
