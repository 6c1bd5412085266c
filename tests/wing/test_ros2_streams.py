"""The drone as standard ROS 2 topics (companion --ros2-topics, companion/ros2_streams.py), seen by an
independent implementation of rmw_zenoh's format: a real companion process on the built-in simulator
(``--px4 sim``), a Zenoh router as rmw_zenohd, and the zenoh-ros2-sdk peer (tests/ros2_peer.py), which
subscribes to /<id>/pose and /<id>/imu with its own .msg files and hashes. The values must be the
vehicle's at rest on the ground in ROS's frames: ENU pose near the origin, gravity +z in FLU.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

from conftest import ROOT, fresh_domain, kill_process, stop_process, wait_for
from ros2_peer import router, start_peer, write_msgs

from zenoh_robot.frames import enu_quaternion, frd_to_flu, ned_to_enu

DRONE = "uavros"

PEER = r"""
import json, sys, threading
import zenoh_ros2_sdk.message_registry as registry
registry._registry = registry.MessageRegistry(sys.argv[1])
from zenoh_ros2_sdk import ROS2Subscriber
port, domain, drone = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
common = dict(domain_id=domain, router_ip="127.0.0.1", router_port=port, namespace="/sdk", node_name="sdk_viewer")
lock = threading.Lock()

def out(**kw):
    with lock:
        sys.stdout.write(json.dumps(kw) + "\n")
        sys.stdout.flush()

def pose(msg):
    p, q = msg.pose.position, msg.pose.orientation
    out(got="pose", type=type(msg).__name__, frame=msg.header.frame_id, sec=msg.header.stamp.sec,
        xyz=[p.x, p.y, p.z], q=[q.x, q.y, q.z, q.w])

def imu(msg):
    a, g = msg.linear_acceleration, msg.angular_velocity
    out(got="imu", type=type(msg).__name__, frame=msg.header.frame_id, sec=msg.header.stamp.sec,
        acc=[a.x, a.y, a.z], gyro=[g.x, g.y, g.z], cov0=float(msg.orientation_covariance[0]))

subs = [ROS2Subscriber(f"/{drone}/pose", "geometry_msgs/msg/PoseStamped", pose, **common),
        ROS2Subscriber(f"/{drone}/imu", "sensor_msgs/msg/Imu", imu, **common)]
out(ready=True)
for line in sys.stdin:
    if line.strip() == "quit":
        break
"""


def test_frames_follow_rep_103() -> None:
    # NED (north 1, east 2, down 3) is ENU (east 2, north 1, up -3); FRD's y and z turn over in FLU.
    assert ned_to_enu(1.0, 2.0, 3.0) == (2.0, 1.0, -3.0)
    assert frd_to_flu(1.0, 2.0, 3.0) == (1.0, -2.0, -3.0)
    # Facing north in NED (yaw 0) is facing +y in ENU: a quarter turn about z.
    x, y, z, w = enu_quaternion(0.0, 0.0, 0.0)
    assert math.isclose(z, math.sqrt(0.5)) and math.isclose(w, math.sqrt(0.5)) and x == 0.0 and y == 0.0
    # Facing east in NED (yaw pi/2) is ENU's identity.
    assert all(math.isclose(a, b, abs_tol=1e-12) for a, b in zip(enu_quaternion(0.0, 0.0, math.pi / 2),
                                                                   (0.0, 0.0, 0.0, 1.0), strict=True))


def test_a_ros2_peer_receives_the_companions_pose_and_imu(tmp_path: Path) -> None:
    msgs = write_msgs(tmp_path / "msgs", ["geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu"])
    domain = fresh_domain()
    with router() as port:
        companion = subprocess.Popen(
            [sys.executable, "-m", "companion", "--id", DRONE, "--px4", "sim", "--profile", "reliable",
             "--ros2-topics", "--ros-domain-id", str(domain), "--camera", "none", "--no-topic-statistics",
             "-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0"],
            cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1", "ZR_DOMAIN": str(fresh_domain()),
                 "ZENOH_CONFIG_OVERRIDE": "scouting/multicast/enabled=false"})
        peer = start_peer(PEER, str(msgs), str(port), str(domain), DRONE)
        try:
            assert wait_for(lambda: peer.find("ready"), 30.0), "".join(peer.raw)[-3000:]
            assert wait_for(lambda: len(peer.find("got", "pose")) >= 3 and len(peer.find("got", "imu")) >= 3, 30.0), \
                f"peer: {''.join(peer.raw)[-2000:]}\ncompanion: {stop_process(companion)[-3000:]}"
        finally:
            try:
                peer.send("quit")
                peer.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                kill_process(peer.proc)
            out = stop_process(companion)
    assert f"ROS 2 topics on domain {domain}: /{DRONE}/imu, /{DRONE}/pose" in out, out[-3000:]

    pose = peer.find("got", "pose")[-1]
    assert pose["type"] == "geometry_msgs__msg__PoseStamped" and pose["frame"] == "map"
    assert pose["sec"] > 1_600_000_000                      # a wall-clock header stamp, as ROS time is
    assert all(abs(v) < 1.0 for v in pose["xyz"]), pose      # on the ground at home
    assert math.isclose(math.fsum(v * v for v in pose["q"]), 1.0, rel_tol=1e-6), pose   # a unit quaternion

    imu = peer.find("got", "imu")[-1]
    assert imu["type"] == "sensor_msgs__msg__Imu" and imu["frame"] == "base_link" and imu["sec"] > 1_600_000_000
    assert 9.0 < imu["acc"][2] < 10.6, imu                  # at rest, FLU: the accelerometer reads +g up
    assert abs(imu["acc"][0]) < 1.0 and abs(imu["acc"][1]) < 1.0, imu
    assert all(abs(v) < 0.5 for v in imu["gyro"]), imu
    assert imu["cov0"] == 0.0, imu                          # ATTITUDE arrived: an orientation, not -1 (none)
