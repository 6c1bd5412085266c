"""The drone's long commands as ROS 2 actions: takeoff, goto and land (the companion's FlightActions).

Their definitions are the ``.action`` files beside this module (ROS package ``zenoh_robot_drone``), so a
ROS 2 workspace builds the same types (same RIHS01 hashes) and an rclpy ``ActionClient`` calls
``/<drone>/takeoff`` like any action. Every goal names its sender (``client_id``): it passes the same
control gate as the command service (hold control, or take it when nobody holds it).

Installed, the package's ``zenoh_robot.ros2_types`` entry point (:func:`register`) hands the texts to
``zenoh_robot.ros2``, so ``zenoh-robot action send_goal /uav1/takeoff zenoh_robot_drone/action/Takeoff
'{client_id: gcs1, altitude_m: 5}'`` needs no file.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from importlib import resources
from typing import Any

PACKAGE = "zenoh_robot_drone"
TAKEOFF = f"{PACKAGE}/action/Takeoff"
GOTO = f"{PACKAGE}/action/Goto"
LAND = f"{PACKAGE}/action/Land"
ACTIONS = (TAKEOFF, GOTO, LAND)
# Where the drone offers them, under its namespace (/uav1/takeoff).
ACTION_NAMES = {TAKEOFF: "takeoff", GOTO: "goto", LAND: "land"}


def definition(name: str) -> str:
    """The ``.action`` text of one of :data:`ACTIONS`."""
    if name not in ACTIONS:
        raise KeyError(f"{name!r} is not one of the drone's actions: {', '.join(ACTIONS)}")
    return resources.files(__package__).joinpath("action", name.rsplit("/", 1)[1] + ".action").read_text("utf-8")


def register() -> None:
    """The ``zenoh_robot.ros2_types`` entry point ``zenoh_robot_drone``: every text to zenoh_robot.ros2."""
    from zenoh_robot.ros2.actions import provide_action

    for name in ACTIONS:
        provide_action(name, definition(name))


@dataclass(frozen=True)
class DroneActionTypes:
    takeoff: Any       # zenoh_robot.ros2.Ros2ActionType (needs the ros2 extra)
    goto: Any
    land: Any


def action_types() -> DroneActionTypes:
    """The three types (made once; needs the ``ros2`` extra, rosbags: ImportError without it)."""
    from zenoh_robot.ros2 import ros2_action_type

    # Without rosbags the types cannot be made: an ImportError says so as what it is (ros2_action_type would
    # report it as a bad definition).
    if importlib.util.find_spec("rosbags") is None:
        raise ImportError("rosbags is not installed (the ros2 extra: pip install 'zenoh-robot[ros2]')")

    return DroneActionTypes(*(ros2_action_type(name, definition(name)) for name in (TAKEOFF, GOTO, LAND)))
