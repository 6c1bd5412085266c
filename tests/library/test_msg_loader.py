"""The .msg loader: ROS syntax -> a message type usable with publishers."""
from __future__ import annotations

from pathlib import Path

import pytest

from zenoh_robot import load_msg
from zenoh_robot.message import type_support
from zenoh_robot.msg_loader import MsgParseError
from zenoh_robot.msgs import Header

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

ROOT = Path(__file__).resolve().parents[2]


def test_humanoid_state_loads_with_fixed_arrays() -> None:
    H = load_msg(ROOT / "configs" / "msg" / "HumanoidState.msg")
    h = H(robot_name="atlas")
    assert type_support(H).name == "msg/HumanoidState"
    assert isinstance(h.header, Header)
    assert len(h.joint_positions) == 28 and len(h.center_of_mass) == 3 and len(h.orientation) == 4
    assert h.in_motion is False and H.NUM_JOINTS == 28
    names = [s.name for s in H._fields_spec]
    assert names == ["header", "robot_name", "torso_height", "center_of_mass", "joint_positions",
                     "joint_velocities", "joint_efforts", "orientation", "linear_velocity",
                     "angular_velocity", "in_motion", "in_safe_mode"]
    h.joint_positions = [0.0] * 27
    with pytest.raises(ValueError, match=r"joint_positions.*float64\[28\] needs 28 elements, got 27"):
        type_support(H).encode(h)


def test_text_definition_with_constants_defaults_unbounded_and_nested() -> None:
    T = load_msg("""
        # a comment line
        int8 MODE_A=1
        string GREETING="hi # not a comment"
        geometry_msgs/Vector3 v
        float32 gain 2.5        # default value
        int32[] counts
        uint8[] blob
        string<=8 short
        float64[<=4] bounded
        Header header
    """, "Mixed")
    t = T()
    assert T.MODE_A == 1 and T.GREETING == "hi # not a comment"
    assert t.gain == 2.5 and t.counts == [] and t.blob == b"" and t.bounded == []
    assert t.v.x == 0.0
    t.counts = [1, 2, 3]
    import msgpack
    assert type_support(T).decode(msgpack.unpackb(msgpack.packb(type_support(T).encode(t)))) == t


@pytest.mark.parametrize("text,match", [
    ("float64 x y z", "not a valid float64"),
    ("nosuch/Type a", "unknown message type"),
    ("float64[x] a", "cannot parse"),
    ("float64 a\nfloat64 a", "duplicate field"),
    ("float64[3] a=1", "constants must be primitive scalars"),
])
def test_errors_name_the_line(text: str, match: str) -> None:
    with pytest.raises(MsgParseError, match=match):
        load_msg(text + "\n", "Bad")


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(MsgParseError, match="no such .msg file"):
        load_msg(tmp_path / "Nope.msg")
