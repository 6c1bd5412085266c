"""Typed messages: wire round trip, type hashes, arrays, images without lists."""
from __future__ import annotations

import msgpack
import numpy as np
import pytest
from wire_helpers import SAMPLE_MESSAGES

from zenoh_robot import Message, array, message
from zenoh_robot.message import lookup, type_support
from zenoh_robot.msgs import Header, Image, JointState, SensorCombined, Setpoint, String, Twist

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


@pytest.mark.parametrize("msg", SAMPLE_MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip_through_msgpack(msg: Message) -> None:
    wire = msgpack.unpackb(msgpack.packb(type_support(type(msg)).encode(msg), use_bin_type=True))
    assert type_support(type(msg)).decode(wire) == msg


def test_type_hash_depends_on_fields_and_names() -> None:
    @message(name="test/A")
    class A(Message):
        x: float = 0.0

    @message(name="test/A2")
    class A2(Message):
        x: float = 0.0

    @message(name="test/A")
    class A3(Message):
        y: float = 0.0

    assert type_support(A).hash != type_support(A3).hash           # same name, other field
    assert type_support(A).hash != type_support(A2).hash           # same fields, other name
    assert len({type_support(Setpoint).hash, type_support(SensorCombined).hash, type_support(Image).hash}) == 3


def test_fixed_array_length_is_checked_on_the_wire() -> None:
    bad = SensorCombined(gyro_rad=[0.0, 1.0])
    with pytest.raises(ValueError, match=r"gyro_rad.*needs 3 elements, got 2"):
        type_support(SensorCombined).encode(bad)


def test_numpy_values_are_accepted_in_fields() -> None:
    from zenoh_robot import envelope
    msg = SensorCombined(gyro_rad=np.array([1.0, 2.0, 3.0], dtype=np.float32))
    ts = type_support(SensorCombined)
    data = envelope.pack(ts.name, ts.hash, 1, 1, 0, ts.encode(msg))
    back = type_support(SensorCombined).decode(envelope.unpack(data).body)
    assert back.gyro_rad == [1.0, 2.0, 3.0]


def test_image_bytes_stay_bytes_and_views_do_not_copy() -> None:
    arr = np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    img = Image.from_array(arr)
    assert (img.width, img.height, img.step, img.encoding) == (320, 240, 960, "rgb8")
    wire = type_support(Image).encode(img)
    assert wire[-1] is img.data  # the body references the bytes; msgpack writes them as one bin
    packed = msgpack.packb(wire, use_bin_type=True)
    assert len(packed) < len(img.data) + 100
    back = type_support(Image).decode(msgpack.unpackb(packed))
    view = back.to_array()
    assert view.base is not None and not view.flags.writeable   # a view over the bytes
    np.testing.assert_array_equal(view, arr)
    mono = Image.from_array(arr[:, :, 0])
    assert mono.encoding == "mono8" and mono.to_array().shape == (240, 320)


def test_image_from_array_rejects_wrong_dtype_and_to_array_checks_size() -> None:
    with pytest.raises(ValueError, match="uint8"):
        Image.from_array(np.zeros((2, 2), dtype=np.float32))
    with pytest.raises(ValueError, match="expected"):
        Image(height=2, width=2, step=6, encoding="rgb8", data=b"123").to_array()


def test_dict_round_trip_and_unknown_field() -> None:
    sp = Setpoint(Header(1, "f", 3), 1, 2, 3)
    assert Setpoint.from_dict(sp.to_dict()) == sp
    with pytest.raises(ValueError, match="no field"):
        Setpoint.from_dict({"q": 1})


def test_lookup_by_full_and_short_name() -> None:
    assert lookup("zenoh_robot/Setpoint") is Setpoint
    assert lookup("Setpoint") is Setpoint
    with pytest.raises(KeyError, match="unknown message type"):
        lookup("NoSuchType")


def test_user_message_with_explicit_types() -> None:
    @message(name="test/Pose3")
    class Pose3(Message):
        position: list[float] = array("float64", 3)
        frame: str = "map"

    p = Pose3()
    assert p.position == [0.0, 0.0, 0.0]
    assert type_support(Pose3).decode(list(type_support(Pose3).encode(p))) == p


@pytest.mark.parametrize("cls, body, field", [
    (Setpoint, [[1, "", 0], 1.0, 2.0, 3.0, 0.0, 1], "is_velocity"),            # int is not bool
    (Setpoint, [[1, "", 0], True, 2.0, 3.0, 0.0, False], "x"),                 # bool is not float
    (Setpoint, [[float("nan"), "", 0], 1.0, 2.0, 3.0, 0.0, False], "header.stamp"),  # NaN only in floats
    (SensorCombined, [[1, "", 0], 0, [0.0, 0.0], 0, 0, [0.0] * 3, 0, [0.0] * 3, 0.0, 0.0], "gyro_rad"),
    (SensorCombined, [[1, "", 0], 0, [0.0] * 3, -1, 0, [0.0] * 3, 0, [0.0] * 3, 0.0, 0.0], "gyro_integral_dt"),
    (SensorCombined, [[1, "", 0], 0, [0.0, "x", 0.0], 0, 0, [0.0] * 3, 0, [0.0] * 3, 0.0, 0.0], "gyro_rad[1]"),
    (Image, [[1, "", 0], 1, 1, "mono8", 0, 1, [1, 300]], "data"),              # a byte over 255
    (JointState, [[1, "", 0], ["a", 3], [], [], []], "name[1]"),
    (Twist, [[1.0, 2.0, 3.0], [0.0, 0.0, "z"]], "angular.z"),
])
def test_decoding_checks_every_field_and_names_it(cls, body, field) -> None:
    from zenoh_robot.message import ValidationError
    with pytest.raises(ValidationError) as info:
        cls._from_wire(body)
    assert info.value.field == field, str(info.value)


def test_decoding_accepts_what_the_schema_allows() -> None:
    sp = Setpoint._from_wire([[5, "map", 2], 1, 2, 3, float("nan"), True])    # ints for floats; NaN in a float
    assert sp.x == 1.0 and type(sp.x) is float and sp.yaw != sp.yaw
    img = Image._from_wire([[1, "", 0], 1, 2, "mono8", 0, 2, [7, 255]])          # numpy-style list of bytes
    assert img.data == bytes([7, 255])
    from zenoh_robot import msg_validate as validate
    with pytest.raises(ValueError, match="at most"):
        String._from_wire(["x" * (validate.MAX_STRING_LEN + 1)])
