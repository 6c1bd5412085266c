"""PX4's frames to ROS's (REP 103): NED world -> ENU, FRD body -> FLU, and the attitude with them.

One place for the conversion every viewer of a drone needs: the companion's ROS 2 topics and the
flight log's Foxglove views both show PX4 data in ROS's frames. Pure math, no dependencies.
"""
from __future__ import annotations

import math


def ned_to_enu(north: float, east: float, down: float) -> tuple[float, float, float]:
    return east, north, -down


def frd_to_flu(x: float, y: float, z: float) -> tuple[float, float, float]:
    return x, -y, -z


def quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of ZYX Euler angles."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def enu_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the FLU body in ENU, from PX4's FRD-in-NED Euler angles (ZYX): NED's yaw turns
    clockwise from north, ENU's counter-clockwise from east."""
    return quaternion(roll, -pitch, math.pi / 2 - yaw)
