"""The drone's telemetry and camera as standard ROS 2 topics, beside the companion's own streams.

With ``companion --ros2-topics`` (or ``--ros2`` / ``--ros-domain-id N``) a second node, ``/<id>/companion``
on ROS 2's wire (rmw_zenoh's format, ``zenoh_robot.wire.ros2_wire``), publishes what PX4 reports as
the types RViz, ``ros2 topic echo`` and ``ros2 bag`` know, so a ROS 2 system sees the drone without a
bridge (docs/ros2.md, "The drone as ROS 2 topics"):

- ``/<id>/imu`` sensor_msgs/Imu from HIGHRES_IMU (frame ``base_link``, FLU), orientation from ATTITUDE;
- ``/<id>/pose`` geometry_msgs/PoseStamped from LOCAL_POSITION_NED + ATTITUDE (frame ``map``, ENU);
- ``/<id>/fix`` sensor_msgs/NavSatFix from GLOBAL_POSITION_INT;
- ``/<id>/battery`` sensor_msgs/BatteryState from BATTERY_STATUS;
- ``/<id>/image/compressed`` sensor_msgs/CompressedImage (JPEG) from the camera, at most
  ``image_max_hz``.

Frames follow REP 103/105 as mavros does: PX4's local NED becomes ENU (x east, y north, z up), its
FRD body becomes FLU, and the attitude is turned accordingly (roll, -pitch, pi/2 - yaw). Stamps are
the wall clock when the companion received the sample (ROS time), not PX4's boot time.

Its own Zenoh session: the contract's streams keep their wire format (envelope, sealed) and their
ZR domain, while ROS 2 peers meet on ROS's (no ZR domain prefix; the ROS domain id keeps systems
apart). Threads: the IMU, pose, fix and battery listeners run on px4_link's receive thread (a
publish is thread safe, and nothing heavier runs there); the image listener on the camera thread.
"""
from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from px4_link.telemetry import Attitude, Battery, GlobalPosition, Imu, LocalPosition
from px4_link.vehicle import VehicleLink
from zenoh_robot import Node, SessionConfig
from zenoh_robot.frames import enu_quaternion, frd_to_flu, ned_to_enu
from zenoh_robot.jpeg import encode_jpeg
from zenoh_robot.publisher import PublisherClosed
from zenoh_robot.qos import QoSProfile

log = logging.getLogger("companion")

# A 320x240 JPEG costs ~2 ms of the camera thread: 10 Hz is what RViz needs to see the drone's view and
# keeps the companion's CPU for its own streams (the contract's image stream keeps the camera's rate).
IMAGE_MAX_HZ = 10.0
JPEG_QUALITY = 80
# ROS 2's default profile (reliable, keep last 10, volatile): what `ros2 topic echo`, RViz and
# rosbag2 ask by default, so no ROS tool meets an incompatible QoS.
ROS_QOS = QoSProfile(depth=10)
TOPICS = ("imu", "pose", "fix", "battery", "image/compressed")
_HOST_PORT = re.compile(r"^(?P<proto>tcp|tls|quic)/(?P<host>.+):(?P<port>\d+)$")


def ros2_session(base: SessionConfig) -> SessionConfig:
    """The ROS 2 node's session: the companion's links to peers (connect endpoints, scouting), its TCP
    listen hosts on a free port (its own ports are taken by its own session), and no ZR domain (ROS
    peers' keys carry none). rmw_zenoh's peers listen on tcp/localhost:0 and connect to a router:
    with neither a TCP listener nor a router, a ROS tool could not reach this node (rmw_zenoh #929)."""
    listen = [f"{m['proto']}/{m['host']}:0" for m in map(_HOST_PORT.match, base.listen) if m]
    return SessionConfig(mode="peer", listen=listen or ["tcp/localhost:0"],
                         connect=[e for e in base.connect if _HOST_PORT.match(e)],
                         multicast_scouting=base.multicast_scouting, shared_memory=base.shared_memory, domain=0)


class Ros2Streams:
    """Publishes the drone as standard ROS 2 types (module doc); ``close()`` before the link goes."""

    def __init__(self, link: VehicleLink, drone_id: str, domain_id: int | None, session: SessionConfig, *,
                 image_max_hz: float = IMAGE_MAX_HZ) -> None:
        from zenoh_robot.ros2 import ros2_type  # the ros2 extra: only this flag needs rosbags
        from zenoh_robot.wire import ros2_wire

        self._link = link
        self.wire = ros2_wire(domain_id)
        t = {n: ros2_type(n) for n in (
            "sensor_msgs/msg/Imu", "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/NavSatFix",
            "sensor_msgs/msg/BatteryState", "sensor_msgs/msg/CompressedImage", "std_msgs/msg/Header",
            "builtin_interfaces/msg/Time", "geometry_msgs/msg/Pose", "geometry_msgs/msg/Point",
            "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Vector3", "sensor_msgs/msg/NavSatStatus")}
        self._t: dict[str, Any] = t   # message classes, built with keywords
        self.node = Node("companion", namespace=drone_id, config=ros2_session(session), wire=self.wire)
        try:
            pub = self.node.create_publisher
            self._imu = pub(t["sensor_msgs/msg/Imu"], "imu", ROS_QOS)
            self._pose = pub(t["geometry_msgs/msg/PoseStamped"], "pose", ROS_QOS)
            self._fix = pub(t["sensor_msgs/msg/NavSatFix"], "fix", ROS_QOS)
            self._battery = pub(t["sensor_msgs/msg/BatteryState"], "battery", ROS_QOS)
            self._image = pub(t["sensor_msgs/msg/CompressedImage"], "image/compressed", ROS_QOS)
        except BaseException:
            self.node.close()
            raise
        self._image_period = 1.0 / image_max_hz if image_max_hz > 0 else math.inf
        self._image_next = 0.0
        self.sent = dict.fromkeys(TOPICS, 0)
        self.image_errors = 0
        self._listeners: list[tuple[Callable[[Any], None], type]] = [
            (self.on_imu, Imu), (self.on_local_position, LocalPosition), (self.on_global_position, GlobalPosition),
            (self.on_battery, Battery)]
        for callback, kind in self._listeners:
            link.telemetry.add_listener(callback, kind)
        log.info("ROS 2 topics on domain %d: %s", self.wire.domain_id,
                 ", ".join(f"/{drone_id}/{name}" for name in TOPICS))

    def close(self) -> None:
        for callback, _ in self._listeners:
            self._link.telemetry.remove_listener(callback)
        self.node.close()

    # -- building blocks ------------------------------------------------------------------------
    def _header(self, frame_id: str) -> Any:
        now = time.time_ns()
        t = self._t
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=now // 1_000_000_000,
                                                                               nanosec=now % 1_000_000_000),
                                        frame_id=frame_id)

    def _orientation(self) -> Any | None:
        att = self._link.telemetry.latest(Attitude)
        if att is None:
            return None
        x, y, z, w = enu_quaternion(att.roll, att.pitch, att.yaw)
        return self._t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def _vector(self, xyz: tuple[float, float, float]) -> Any:
        return self._t["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))

    def _publish(self, name: str, publisher: Any, msg: Any) -> None:
        try:
            publisher.publish(msg)
        except PublisherClosed:   # shutting down: the link's thread outlived the node by a moment
            return
        self.sent[name] += 1

    # -- px4_link's thread ----------------------------------------------------------------------
    def on_imu(self, imu: Imu) -> None:
        q = self._orientation()
        orientation_cov = [0.0] * 9
        if q is None:      # sensor_msgs/Imu: element 0 at -1 says "no orientation estimate"
            q = self._t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
            orientation_cov[0] = -1.0
        self._publish("imu", self._imu, self._t["sensor_msgs/msg/Imu"](
            header=self._header("base_link"), orientation=q, orientation_covariance=orientation_cov,
            angular_velocity=self._vector(frd_to_flu(*imu.gyro_rad)), angular_velocity_covariance=[0.0] * 9,
            linear_acceleration=self._vector(frd_to_flu(*imu.accelerometer_m_s2)),
            linear_acceleration_covariance=[0.0] * 9))

    def on_local_position(self, pos: LocalPosition) -> None:
        t = self._t
        x, y, z = ned_to_enu(pos.x, pos.y, pos.z)
        q = self._orientation() or t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=q)
        self._publish("pose", self._pose, t["geometry_msgs/msg/PoseStamped"](header=self._header("map"), pose=pose))

    def on_global_position(self, fix: GlobalPosition) -> None:
        t = self._t
        status = t["sensor_msgs/msg/NavSatStatus"](status=0, service=1)   # STATUS_FIX, SERVICE_GPS
        self._publish("fix", self._fix, t["sensor_msgs/msg/NavSatFix"](
            header=self._header("base_link"), status=status, latitude=fix.lat_deg, longitude=fix.lon_deg,
            altitude=fix.alt_m, position_covariance=[0.0] * 9, position_covariance_type=0))

    def on_battery(self, batt: Battery) -> None:
        def known(v: float, scale: float = 1.0) -> float:   # MAVLink's -1 means "not measured": NaN in ROS
            return v * scale if math.isfinite(v) and v >= 0 else math.nan
        self._publish("battery", self._battery, self._t["sensor_msgs/msg/BatteryState"](
            header=self._header("base_link"), voltage=known(batt.voltage_v), temperature=batt.temperature_c,
            # ROS counts current negative while discharging; MAVLink positive.
            current=-batt.current_a if math.isfinite(batt.current_a) and batt.current_a >= 0 else math.nan,
            charge=math.nan, capacity=math.nan, design_capacity=math.nan,
            percentage=known(batt.remaining_pct, 0.01), power_supply_status=2,   # DISCHARGING
            power_supply_health=0, power_supply_technology=0, present=True, cell_voltage=[], cell_temperature=[],
            location="", serial_number=""))

    # -- the camera thread ----------------------------------------------------------------------
    def on_frame(self, frame: np.ndarray) -> None:
        now = time.monotonic()
        if now < self._image_next:
            return
        self._image_next += self._image_period
        if self._image_next < now:      # the first frame, or the camera fell behind: from now on
            self._image_next = now + self._image_period
        try:
            data = encode_jpeg(frame, JPEG_QUALITY)
        except Exception as exc:   # never the camera thread's end: the contract's stream goes on
            self.image_errors += 1
            if self.image_errors & (self.image_errors - 1) == 0:    # logged at 1, 2, 4, 8...
                log.warning("ROS 2 image: %s (%d so far)", exc, self.image_errors)
            return
        self._publish("image/compressed", self._image, self._t["sensor_msgs/msg/CompressedImage"](
            header=self._header("camera"), format="jpeg", data=data))
