"""Px4Link against the simulator: real MAVLink bytes over localhost UDP, ephemeral ports."""
from __future__ import annotations

import math
import os
import socket
import statistics
import time
from itertools import pairwise

import pytest
from px4_helpers import FAST_PARAMS, EventLog, silent_to, sim_and_link, wait_armable, wait_for

from px4_link import (
    Attitude,
    Battery,
    CommandDenied,
    CommandTemporarilyRejected,
    CommandTimeout,
    CommandUnsupported,
    ExtendedSysState,
    Geofence,
    GlobalPosition,
    Imu,
    LocalPosition,
    PositionTarget,
    Px4Link,
    SysStatus,
    TargetRefused,
    VelocityTarget,
)
from px4_link.sim import Simulator


def _airborne_offboard(sim, link, z: float = -3.0) -> None:
    """Arm on the ground and climb in OFFBOARD (PX4 takes off towards a setpoint above it)."""
    link.action.arm()
    link.offboard.set_setpoint(PositionTarget(0, 0, z, yaw=0.0))
    link.offboard.start()
    assert sim.wait_for(lambda s: s.altitude > -z - 0.3, 8), sim.position


def test_connects_and_decodes_every_telemetry_type() -> None:
    with sim_and_link(sysid=3) as (sim, link, events):
        st = link.state
        assert st.connected and st.system_id == 3 and st.component_id == 1
        assert st.mode == "AUTO.LOITER" and not st.armed       # PX4 boots disarmed in Hold
        assert st.autopilot == 12 and st.vehicle_type == 2      # MAV_AUTOPILOT_PX4, QUADROTOR
        for kind in (Imu, Attitude, LocalPosition, GlobalPosition, SysStatus, ExtendedSysState):
            assert link.telemetry.wait(kind, 3.0) is not None, kind
        assert link.telemetry.wait(Battery, 4.0) is not None    # 0.5 Hz on PX4's onboard link
        imu = link.telemetry.latest(Imu)
        assert imu.accelerometer_m_s2[2] == pytest.approx(-9.81, abs=0.5)  # resting: -g in FRD
        assert math.hypot(*imu.magnetometer_ga) == pytest.approx(0.47, abs=0.05)
        assert link.telemetry.latest(GlobalPosition).lat_deg == pytest.approx(47.3977, abs=1e-3)
        assert link.wait_until(lambda: link.state.landed is True, 2)
        assert events.names()[0] == "connected"


def test_listener_callbacks_and_callback_errors_do_not_kill_link() -> None:
    got: list[Imu] = []

    def boom(sample) -> None:
        raise RuntimeError("listener bug")

    with sim_and_link() as (sim, link, events):
        link.telemetry.add_listener(got.append, Imu)
        link.telemetry.add_listener(boom)
        link.add_event_listener(lambda n, d: 1 / 0)
        assert wait_for(lambda: len(got) > 10, 3)
        assert all(isinstance(s, Imu) for s in got)
        assert link.stats.callback_errors > 10
        link.action.arm()                                   # still fully working
        assert sim.wait_for(lambda s: s.armed, 2)


def test_arm_takeoff_land_and_auto_disarm() -> None:
    with sim_and_link() as (sim, link, events):
        link.action.arm()
        assert sim.armed and link.wait_until(lambda: link.state.armed, 2)
        link.action.takeoff(2.0)     # low: a shorter climb and landing, PX4's sequence unchanged
        assert sim.wait_for(lambda s: s.altitude > 1.75 and s.mode == "AUTO.LOITER", 10), \
            (sim.position, sim.mode)
        assert link.wait_until(lambda: link.state.landed is False, 2)
        # PX4 refuses a normal disarm in the air ...
        with pytest.raises(CommandTemporarilyRejected):
            link.action.disarm()
        assert sim.armed
        link.action.land()
        assert sim.wait_for(lambda s: s.landed, 10), sim.position
        # ... and disarms by itself COM_DISARM_LAND (2 s) after touchdown.
        assert sim.wait_for(lambda s: not s.armed, 5)
        assert link.wait_until(lambda: not link.state.armed, 3)
        assert "armed_changed" in events.names()
        modes = [c.new for c in sim.mode_log]
        assert modes[:3] == ["AUTO.TAKEOFF", "AUTO.LOITER", "AUTO.LAND"]


def test_offboard_refused_without_stream_accepted_with_one() -> None:
    with sim_and_link() as (sim, link, events):
        link.action.arm()
        with pytest.raises(CommandTemporarilyRejected) as e:
            link.action.set_mode("OFFBOARD")
        assert "offboard" in str(e.value).lower()
        assert sim.mode == "AUTO.LOITER"
        # No warm-up (offboardCheck.cpp): a setpoint within COM_OF_LOSS_T makes OFFBOARD available.
        link.offboard.set_setpoint(PositionTarget(0, 0, -2.0, yaw=0.0))
        link.offboard.start()
        assert sim.mode == "OFFBOARD" and link.state.mode == "OFFBOARD"
        sp = sim.last_setpoint
        assert sp.type_mask == 0x9F8 and sp.frame == 1 and sp.position == (0.0, 0.0, -2.0)
        # The stream runs at the fixed rate (20 Hz): one setpoint per 50 ms tick, the median spacing of 40
        # as the simulator received them (a stalled tick on a loaded machine moves one spacing, not the median).
        n0 = len(sim.setpoint_arrivals)
        assert wait_for(lambda: len(sim.setpoint_arrivals) >= n0 + 41, 10)
        t = [at for at, _ in sim.setpoint_arrivals[n0:n0 + 41]]
        spacing = statistics.median(b - a for a, b in pairwise(t))
        assert 0.04 <= spacing <= 0.06, spacing


def test_vehicle_reaches_position_and_velocity_setpoints() -> None:
    with sim_and_link() as (sim, link, events):
        _airborne_offboard(sim, link)
        target = (4.0, -3.0, -5.0)
        # Walk the setpoint there (a single 6 m jump would fail the jump check).
        for i in range(1, 21):
            link.offboard.set_setpoint(PositionTarget(*(c * i / 20 for c in target[:2]),
                                               -3.0 + (target[2] + 3.0) * i / 20, yaw=1.0))
            time.sleep(0.05)
        assert sim.wait_for(lambda s: math.dist(s.position, target) < 0.2, 10), sim.position
        assert sim.wait_for(lambda s: abs(s.vehicle.yaw - 1.0) < 0.05, 5)
        lp = link.telemetry.wait(LocalPosition, 2)
        assert math.dist(lp.position, target) < 0.3
        link.offboard.set_setpoint(VelocityTarget(1.0, 0.0, 0.0, yaw=1.0))
        assert sim.last_setpoint is not None
        assert wait_for(lambda: sim.last_setpoint.type_mask == 0x9C7, 1)
        assert sim.wait_for(lambda s: s.velocity[0] > 0.9, 5), sim.velocity
        link.offboard.stop()                     # switch to Hold, then stop streaming
        assert sim.mode == "AUTO.LOITER" and "offboard_lost" not in events.names()


def test_stream_loss_leaves_offboard_within_com_of_loss_t() -> None:
    with sim_and_link() as (sim, link, events):
        _airborne_offboard(sim, link)
        assert sim.get_param("COM_OF_LOSS_T") == 1.0
        link.offboard.stop_stream()
        assert sim.wait_for(lambda s: s.mode != "OFFBOARD", 5.0)
        # Real PX4 SITL: ~1.4 s after the last setpoint (COM_OF_LOSS_T + detection latency).
        elapsed = silent_to(sim, sim.mode)
        assert 1.1 < elapsed < 1.8, elapsed
        # COM_OBL_RC_ACT = 0 (Position) needs RC; without it PX4 falls back to Return.
        assert sim.mode == "AUTO.RTL" and sim.mode_log[-1].reason == "failsafe: offboard loss"
        assert sim.system_status == 5 and sim.failsafe_log[-1].action == "AUTO.RTL"
        assert link.wait_until(lambda: "offboard_lost" in events.names(), 3)
        assert link.wait_until(lambda: link.state.system_status == 5, 2.0)   # CRITICAL
        assert sim.armed   # RTL at home: it lands where it is


def test_failsafe_action_follows_com_obl_rc_act_set_over_mavlink() -> None:
    with sim_and_link() as (sim, link, events):
        assert link.param.get("COM_OBL_RC_ACT") == 0
        assert link.param.get("COM_OF_LOSS_T") == pytest.approx(1.0)
        assert link.param.set("COM_OBL_RC_ACT", 5) == 5            # 5 = Hold
        assert link.param.set("COM_OF_LOSS_T", 0.5) == pytest.approx(0.5)
        assert sim.get_param("COM_OBL_RC_ACT") == 5
        _airborne_offboard(sim, link)
        link.offboard.stop_stream()
        assert sim.wait_for(lambda s: s.mode == "AUTO.LOITER", 5.0), sim.mode
        assert silent_to(sim, "AUTO.LOITER") < 1.0      # COM_OF_LOSS_T 0.5 s + PX4's detection latency


def test_invalid_setpoints_rejected_and_never_reach_vehicle() -> None:
    with sim_and_link(link_kwargs={"geofence": Geofence(max_distance_m=20, max_altitude_m=10),
                                   "max_speed": 5.0}) as (sim, link, events):
        bad = [PositionTarget(math.nan, 0, -2), PositionTarget(0, 0, -2, yaw=math.inf),
               PositionTarget(30, 0, -2), PositionTarget(0, 0, -15),
               VelocityTarget(0, 8, 0)]
        for sp in bad:
            with pytest.raises(TargetRefused):
                link.offboard.set_setpoint(sp)
        time.sleep(0.3)
        assert sim.setpoints_received == 0 and link.offboard.setpoint is None
        link.offboard.set_setpoint(PositionTarget(0, 0, -2))
        assert wait_for(lambda: sim.setpoints_received > 0, 2)
        with pytest.raises(TargetRefused) as e:
            link.offboard.set_setpoint(PositionTarget(10, 0, -2))      # 10 m in 1 tick at 5 m/s
        assert e.value.reason == "too_fast"
        time.sleep(0.3)
        assert sim.last_setpoint.position == (0.0, 0.0, -2.0)
        assert link.offboard.setpoint == PositionTarget(0, 0, -2)
        assert link.stats.setpoints_rejected == len(bad) + 1
        assert events.count("setpoint_rejected") == len(bad) + 1


def test_command_errors_raise_the_right_exception() -> None:
    with sim_and_link() as (sim, link, events):
        # Disarmed, PX4 accepts any mode (UserModeIntention.cpp) and refuses arming in one that
        # cannot run (HealthAndArmingChecks): no RC for POSCTL, no mission for MISSION.
        for mode in ("POSCTL", "MISSION"):
            link.action.set_mode(mode)
            with pytest.raises(CommandTemporarilyRejected):
                link.action.arm()
        with pytest.raises(CommandDenied):
            link.send_command(185, 1)          # DO_FLIGHTTERMINATION while disarmed
        with pytest.raises(CommandUnsupported):
            link.send_command(31000, 1)        # MAV_CMD_USER_1: nobody handles it
        link.action.set_mode("LAND")                  # LAND is always allowed (PX4's emergency mode)
        with pytest.raises(CommandTemporarilyRejected):
            link.action.arm()                         # but arming in LAND is not
        link.action.hold()
        link.action.arm()
        assert sim.armed
        sim.stop()                             # vehicle gone: retries, then a timeout
        t0 = time.monotonic()
        with pytest.raises(CommandTimeout):
            link.send_command(400, 0, timeout=0.2, retries=2)
        assert time.monotonic() - t0 >= 0.5
        assert {r for _, c, r in sim.command_log if c == 176} == {0}    # every mode accepted disarmed
        results = [r for _, c, r in sim.command_log if c == 400]
        assert 1 in results and 0 in results


def test_message_interval_gives_200hz_imu() -> None:
    with sim_and_link() as (sim, link, events):
        assert sim.message_rates["HIGHRES_IMU"] == 50.0       # PX4 onboard default
        assert sim.message_rates["ATTITUDE"] == 100.0
        assert sim.message_rates["LOCAL_POSITION_NED"] == 30.0
        got: list[int] = []
        link.telemetry.add_listener(lambda s: got.append(s.timestamp_us), Imu)
        link.telemetry.request_message_interval("HIGHRES_IMU", 200)
        assert sim.message_rates["HIGHRES_IMU"] == pytest.approx(200.0)
        # PX4 sends at the first sensor sample (247 Hz) after the interval: every 2nd, ~8.1 ms apart (~123 Hz),
        # by the samples' own timestamps (PX4's clock: a loaded receiver does not move them).
        n0 = len(got) + 10
        assert wait_for(lambda: len(got) >= n0 + 61, 10)
        stamps = got[n0:n0 + 61]
        spacing_ms = statistics.median((b - a) / 1000 for a, b in pairwise(stamps))
        assert 7.5 <= spacing_ms <= 9.0, spacing_ms
        link.telemetry.request_message_interval("ATTITUDE", 0)          # disable
        assert sim.message_rates["ATTITUDE"] == 0.0
        with pytest.raises(Exception):
            link.telemetry.request_message_interval(12345, 10)          # unknown id -> FAILED


def test_garbage_udp_is_counted_never_fatal() -> None:
    with sim_and_link() as (sim, link, events):
        junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            frame = bytearray(b"\xfd\x09\x00\x00\x01\x01\x01\x00\x00\x00" + bytes(9) + b"\x00\x00")
            for i in range(50):
                junk.sendto(os.urandom(1 + i * 7), ("127.0.0.1", link.local_port))
                junk.sendto(bytes(frame), ("127.0.0.1", link.local_port))   # bad CRC
                junk.sendto(os.urandom(64), ("127.0.0.1", sim.port))
            assert wait_for(lambda: link.stats.crc_errors >= 40, 3), link.stats
            s = link.stats
            assert s.garbage_bytes > 1000 and s.bad_frames >= 50
            assert wait_for(lambda: sim.bad_frames_received >= 40, 3)
            # Still connected, still decoding, and replies still go to the vehicle.
            assert link.connected and link.telemetry.wait(Imu, 1.0) is not None
            link.action.arm()
            assert sim.armed
        finally:
            junk.close()


def test_two_simulators_side_by_side() -> None:
    with sim_and_link(sysid=1) as (sim1, link1, _), sim_and_link(sysid=2) as (sim2, link2, _):
        assert link1.system_id == 1 and link2.system_id == 2
        link2.action.arm()
        link2.action.takeoff()
        assert sim2.wait_for(lambda s: s.altitude > 1.5, 8)
        assert not sim1.armed and sim1.altitude == 0.0
        assert link1.state.mode == "AUTO.LOITER" and link1.telemetry.latest(LocalPosition).z == 0.0


def test_two_simulators_one_port_link_picks_its_system_id() -> None:
    events = EventLog()
    with Px4Link("udpin:127.0.0.1:0", target_system=2, on_event=events) as link:
        with Simulator(1, port=0, target_port=link.local_port, params=FAST_PARAMS) as sim1, \
                Simulator(2, port=0, target_port=link.local_port, params=FAST_PARAMS) as sim2:
            assert link.wait_connected(5)
            assert link.system_id == 2
            assert wait_for(lambda: link.stats.other_system_messages > 50, 3)
            wait_armable(link)
            link.action.arm()
            assert sim2.armed and not sim1.armed
            assert link.telemetry.wait(Imu, 1).system_id == 2
