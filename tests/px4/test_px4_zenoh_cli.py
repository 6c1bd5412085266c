"""``zenoh-robot topic list/echo --ros2`` see PX4's own Zenoh topics with decoded fields.

PX4's zenoh module (here the built-in simulator of its protocol, a client of a router as PX4 is) sends
px4_msgs with 0-31 leftover bytes after each CDR body: the CLI finds px4_msgs through the
``zenoh_robot.ros2_types`` entry point (the tools never import the drone wing) and reads the body as
rmw_zenoh does, ignoring what follows it. Before, PX4's types were unknown to the tools and a strict
CDR reader refused every PX4 sample.
"""
from __future__ import annotations

import subprocess
import time

import zenoh
from conftest import CLI
from px4_zenoh_probe import _conf, free_port

from px4_zenoh.sim import ZenohSimulator


def test_topic_list_and_echo_show_px4s_fmu_topics_decoded() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    common = ["--ros2", "-m", "client", "-e", endpoint]
    with zenoh.open(_conf("router", "listen/endpoints", endpoint)), ZenohSimulator(connect=endpoint):
        time.sleep(1.0)
        listed = subprocess.run(CLI + ["topic", "list", "-t", *common], capture_output=True, text=True, timeout=60)
        assert listed.returncode == 0, listed.stderr
        assert "/fmu/out/vehicle_status [px4_msgs/msg/VehicleStatus]" in listed.stdout
        assert "/fmu/out/vehicle_gps_position [px4_msgs/msg/SensorGps]" in listed.stdout   # the type, not the topic
        echo = subprocess.run(CLI + ["topic", "echo", "/fmu/out/sensor_combined", "--once", *common],
                              capture_output=True, text=True, timeout=60)
        assert echo.returncode == 0, echo.stderr
        fields = dict(line.split(": ", 1) for line in echo.stdout.splitlines() if ": " in line)
        assert int(fields["gyro_integral_dt"]) == 4000 and int(fields["timestamp"]) > 0
        accel_z = float(echo.stdout.split("accelerometer_m_s2:")[1].split("- ")[3].split()[0])
        assert -10.5 < accel_z < -9.0          # FRD: gravity reads negative z on the ground
        status = subprocess.run(CLI + ["topic", "echo", "/fmu/out/vehicle_status", "--once", "--field",
                                       "arming_state", *common], capture_output=True, text=True, timeout=60)
        assert status.returncode == 0 and status.stdout.split()[0] == "1", status.stdout + status.stderr   # disarmed
