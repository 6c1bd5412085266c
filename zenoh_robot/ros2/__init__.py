"""ROS 2 message and service types at run time, for nodes on the ROS 2 wire (``zenoh_robot.wire.ros2``).

``ros2_type("std_msgs/msg/String")`` is a zenoh-robot message class (an ``@message`` dataclass,
validated like any other) whose type name and hash are ROS 2's (``std_msgs/msg/String``,
``RIHS01_…``) and which carries its CDR codec. Definitions come from rosbags' typestore (the
standard packages) or from ``.msg`` text (:func:`load_ros2_msg`): no ROS install, no build step.
``ros2_service_type("example_interfaces/srv/AddTwoInts")`` is a service's two halves, hash and name
(services.py); ``ros2_action_type("example_interfaces/action/Fibonacci")`` every type an action
derives (actions.py). Needs the ``ros2`` extra (rosbags); ``import zenoh_robot`` never loads this package.
See docs/ros2.md.

Modules, one job each: types (message classes, CDR codec, RIHS01 hashing, definitions), services
(.srv -> request/response types and the service hash), actions (.action -> the derived messages and services).
"""
from .actions import KNOWN_ACTIONS, Ros2ActionType, action_definition, ros2_action_type
from .services import (
    KNOWN_SERVICES,
    Ros2ServiceType,
    Ros2TypeError,
    decode_cdr,
    encode_cdr,
    ros2_service_type,
    service_type_of,
)
from .types import (
    Ros2Codec,
    cdr_codec,
    dependencies,
    is_ros2_type,
    load_ros2_msg,
    msg_definition,
    rihs01,
    ros2_type,
    typestore,
)

__all__ = [
    "KNOWN_ACTIONS",
    "KNOWN_SERVICES",
    "Ros2ActionType",
    "Ros2Codec",
    "Ros2ServiceType",
    "Ros2TypeError",
    "action_definition",
    "cdr_codec",
    "decode_cdr",
    "dependencies",
    "encode_cdr",
    "is_ros2_type",
    "load_ros2_msg",
    "msg_definition",
    "rihs01",
    "ros2_action_type",
    "ros2_service_type",
    "ros2_type",
    "service_type_of",
    "typestore",
]
