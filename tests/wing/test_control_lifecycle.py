"""The companion's offboard lifecycle, control and command policy, in-process with real parts:
the built-in simulator over real MAVLink/UDP, px4_link, the Companion and GCS objects on real
Zenoh sessions linked over loopback."""
from __future__ import annotations

import threading
import time

import pytest
from conftest import wait_for
from rigs import PROFILE, rig, take_off

from drone_contract.messages import Command
from gcs.app import Gcs, GcsConfig
from gcs.mission import run_mission


def test_arm_after_a_mission_stays_on_the_ground_and_nothing_streams_after_landing(ns: str) -> None:
    with rig(ns) as r:
        take_off(r)
        assert r.op.command("land").success
        # The GCS keeps streaming its last target: exactly the real-SITL failure.
        assert wait_for(lambda: r.sim.landed and not r.sim.armed, 30), "never landed and disarmed"
        assert wait_for(lambda: r.sim.mode == "AUTO.LOITER", 5), f"left in {r.sim.mode} after landing"
        received = r.sim.setpoints_received
        time.sleep(1.5)
        assert r.sim.setpoints_received == received, "setpoints still reach PX4 after landing"
        assert r.sim.setpoints_since_landed == 0
        assert not r.link.offboard.streaming and r.op.state is not None
        res = r.op.command("arm")
        assert res.success, res.message
        time.sleep(3.0)
        assert r.sim.altitude < 0.3, f"took off by itself to {r.sim.altitude:.1f} m"
        assert r.sim.setpoints_received == received
        # Setpoints outside a session were reported as not forwarded, never silently dropped.
        assert "setpoint_ignored" in r.op.kinds("op")
        assert r.op.command("disarm").success


def test_deadline_missed_holds_then_stops_streaming_and_resumes_only_when_asked(ns: str) -> None:
    with rig(ns) as r:
        take_off(r)
        r.op.target = None   # the GCS dies
        assert wait_for(lambda: r.sim.mode == "AUTO.LOITER", 5), r.sim.mode
        assert wait_for(lambda: not r.link.offboard.streaming, 2)
        assert wait_for(lambda: "setpoint_deadline_missed" in r.op.kinds(), 5)
        assert r.sim.armed and not r.sim.landed
        assert not r.sim.failsafe_log, "PX4's own failsafe fired: our HOLD came too late"
        x, y, z = r.sim.position
        r.op.target = (x, y, z)   # back, from where the drone is
        time.sleep(1.5)
        assert r.sim.mode == "AUTO.LOITER", "resumed without being asked"
        res = r.op.command("offboard_start")
        assert res.success, res.message
        assert wait_for(lambda: r.sim.mode == "OFFBOARD", 5)
        assert r.op.command("land").success


def test_resume_30_m_from_home_and_the_refusal_says_why(ns: str) -> None:
    with rig(ns) as r:
        take_off(r, 3.0)
        # Fly 30 m north, the target never more than 8 m ahead of the vehicle.
        while r.sim.position[0] < 29.0:
            r.op.target = (min(30.0, r.sim.position[0] + 8.0), 0.0, -3.0)
            time.sleep(0.1)
        assert r.op.command("hold").success
        r.op.target = (0.0, 0.0, -5.0)   # a restarted GCS that streams its old hover point
        time.sleep(0.5)
        res = r.op.command("offboard_start")
        assert not res.success
        assert "setpoints refused: jump" in res.message and "from vehicle position > 1" in res.message, res.message
        assert r.sim.mode == "AUTO.LOITER"
        # The real GCS streams from the drone's current position.
        r.op.target = None
        gcs = Gcs(r.ground, GcsConfig(drones=[ns], pattern="hover", altitude=3.0, profile=PROFILE, client_id="op"))
        drone = gcs.drones[ns]
        assert wait_for(lambda: drone.setpoints_sent > 5, 10)
        res = drone.command("offboard_start")
        assert res.success, res.message
        assert wait_for(lambda: r.sim.mode == "OFFBOARD", 5)
        time.sleep(2.0)
        assert r.sim.position[0] > 25.0, f"flew back towards home: {r.sim.position}"
        assert r.sim.mode == "OFFBOARD" and r.companion.lifecycle.state.value == "active"
        gcs.streaming = False


def test_mission_interrupted_by_a_failsafe_reports_failure(ns: str) -> None:
    with rig(ns) as r:
        gcs = Gcs(r.ground, GcsConfig(drones=[ns], pattern="square", altitude=2.5, size=4.0, profile=PROFILE,
                                      client_id="op", auto_fly=False))
        lines: list[str] = []
        result: dict = {}
        t = threading.Thread(target=lambda: result.update(run_mission(gcs, ns, 30.0, lines.append)), daemon=True)
        t.start()
        assert wait_for(lambda: r.sim.mode == "OFFBOARD" and gcs.drones[ns].fly, 40), lines
        time.sleep(1.0)
        gcs.streaming = False   # the link to the drone goes silent mid pattern
        t.join(timeout=20)
        assert not t.is_alive()
        assert not result["ok"], result
        assert "FAILED" in result["result"] and "setpoint_deadline_missed" in result["result"], result["result"]
        assert r.sim.mode == "AUTO.LOITER"


def test_one_gcs_in_control_others_refused_and_told_why(ns: str) -> None:
    with rig(ns) as r:
        take_off(r)
        r.other.target = (0.0, 0.0, -2.5)   # a second GCS streams too
        res = r.other.command("land")
        assert not res.success and "op is in control" in res.message, res.message
        res = r.other.command("offboard_start")
        assert not res.success and "op is in control" in res.message
        # Its setpoints are refused and reported to it, and the refusal reaches the GCS in control too.
        assert wait_for(lambda: "setpoint_rejected" in r.other.kinds("intruder"), 5)
        # Each GCS hears the event on its own subscription: wait for the one in control too.
        assert wait_for(lambda: any(e.kind == "setpoint_rejected" and e.client_id == "intruder"
                                    for e in r.op.events), 5)
        ev = next(e for e in r.op.events if e.kind == "setpoint_rejected" and e.client_id == "intruder")
        assert "op is in control" in ev.detail
        assert wait_for(lambda: "control_refused" in r.op.kinds("intruder"), 5)
        assert r.companion.control.counters.refused_setpoints > 0
        # Rate-limited: far fewer events than refused setpoints.
        time.sleep(2.5)
        n_events = r.other.kinds("intruder").count("setpoint_rejected")
        assert n_events <= 3 < r.companion.control.counters.refused_setpoints
        assert r.sim.mode == "OFFBOARD" and r.op.state is not None and r.op.state.controller == "op"
        # An explicit takeover works, and the GCS that lost control is told.
        res = r.other.command("take_control", force=True)
        assert res.success and "taken from op" in res.message, res.message
        assert wait_for(lambda: "control_lost" in r.op.kinds("op"), 5)
        assert not r.op.command("hold").success
        assert r.other.command("land").success


def test_command_policy_force_disarm_and_param_allow_list(ns: str) -> None:
    with rig(ns) as r:
        take_off(r)
        res = r.op.command("disarm", force=True)
        assert not res.success and "--allow-force-disarm" in res.message, res.message
        assert r.sim.armed
        res = r.op.command("set_param", 0.0, "COM_OF_LOSS_T")
        assert not res.success and "allow-list" in res.message, res.message
        assert r.sim.get_param("COM_OF_LOSS_T") != 0.0
        res = r.op.command("set_param", 1.5, "MPC_LAND_SPEED")
        assert res.success, res.message
        assert r.sim.get_param("MPC_LAND_SPEED") == pytest.approx(1.5)
        res = r.op.client.call(Command("arm", 0.0, "", False, ""), timeout=10)
        assert not res.success and "client_id" in res.message


def test_sensor_rate_is_measured_and_a_shortfall_is_reported(ns: str) -> None:
    with rig(ns, sensor_rate_hz=400.0) as r:
        r.companion.telemetry.request_rates()
        assert wait_for(lambda: r.op.state is not None and r.op.state.sensor_rate_hz > 0, 10)
        delivered = r.sim.delivered_rates["HIGHRES_IMU"]
        assert r.op.state.sensor_rate_requested_hz == 400.0
        assert wait_for(lambda: abs(r.op.state.sensor_rate_hz - delivered) < 0.25 * delivered, 10), \
            (r.op.state.sensor_rate_hz, delivered)
        if delivered < 0.9 * 400:
            assert wait_for(lambda: "sensor_rate_low" in r.op.kinds(), 5)


def test_gcs_without_mission_flies_its_pattern_from_where_the_drone_is(ns: str) -> None:
    with rig(ns) as r:
        take_off(r, 2.5)
        assert r.op.command("hold").success
        x0, y0, _ = r.sim.position
        r.op.target = None
        gcs = Gcs(r.ground, GcsConfig(drones=[ns], pattern="line", altitude=2.5, size=6.0, speed=2.0,
                                      profile=PROFILE, client_id="op"))
        drone = gcs.drones[ns]
        assert wait_for(lambda: drone.setpoints_sent > 5, 10)
        assert drone.command("offboard_start").success
        assert wait_for(lambda: r.sim.position[0] > x0 + 3.0, 15), "the pattern was not flown"
        assert abs(r.sim.position[1] - y0) < 1.5
        assert r.sim.mode == "OFFBOARD"
        gcs.streaming = False
