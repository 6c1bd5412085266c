"""ROS 2 message types at run time, for nodes on the ROS 2 wire (``zenoh_robot.wire.ros2``).

``ros2_type("std_msgs/msg/String")`` is a zenoh-robot message class (an ``@message`` dataclass,
validated like any other) whose type name and hash are ROS 2's (``std_msgs/msg/String``,
``RIHS01_…``) and which carries its CDR codec. Definitions come from rosbags' typestore (the
standard packages) or from ``.msg`` text (:func:`load_ros2_msg`): no ROS install, no build step.
Needs the ``ros2`` extra (rosbags); ``import zenoh_robot`` never loads this package. See docs/ros2.md.
"""
from .types import Ros2Codec, cdr_codec, dependencies, is_ros2_type, load_ros2_msg, msg_definition, ros2_type, typestore

__all__ = ["Ros2Codec", "cdr_codec", "dependencies", "is_ros2_type", "load_ros2_msg", "msg_definition", "ros2_type",
           "typestore"]
