"""Messages and hostile-input tools shared by the wire, pub/sub and fuzzing tests.

- ``SAMPLE_MESSAGES``: one message of each kind (arrays, nested, a 230 kB image), for round trips.
- ``ArmRequest``/``ArmResponse``: a small service type; ``KEEP_ALL``: a subscription that keeps everything.
- ``raw_put``: what an attacker's own zenoh-python session can do: put hand-made bytes on a key.
"""
from __future__ import annotations

import numpy as np

from zenoh_robot import Message, QoSProfile, message, ros_field
from zenoh_robot.msgs import (
    Float32,
    Header,
    Image,
    JointState,
    Quaternion,
    SensorCombined,
    Setpoint,
    String,
    Twist,
    Vector3,
)
from zenoh_robot.qos import HistoryPolicy

SAMPLE_MESSAGES = [
    Setpoint(Header(5, "map", 2), 1.0, 2.0, -3.0, 0.5, True),
    SensorCombined(Header(1), 99, [0.1, 0.2, 0.3], 4000, 0, [0.0, 0.0, -9.8], 4000, [0.2, 0.0, 0.4], 12.5, 21.0),
    Image.from_array(np.arange(240 * 320 * 3, dtype=np.uint8).reshape(240, 320, 3) % 251),
    String("hello"), Float32(1.5), Vector3(1, 2, 3), Quaternion(0, 0, 0, 1),
    Twist(Vector3(1, 0, 0), Vector3(0, 0, 0.3)),
    JointState(Header(), ["a", "b"], [0.1, 0.2], [0.0, 0.0], [1.0, 2.0]),
]


# Registered under test_hardening/ (their first home): the type names are part of the wire.
@message(name="test_hardening/ArmRequest")
class ArmRequest(Message):
    force: bool = False
    value: int = ros_field("int32", 0)
    reason: str = ""


@message(name="test_hardening/ArmResponse")
class ArmResponse(Message):
    ok: bool = False


KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=0)


def raw_put(session, key: str):
    """An attacker's put that Zenoh does not drop when its queue is full (a flood must arrive whole)."""
    import zenoh
    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK).put
