"""The simulator against real PX4 SITL (traces in ../shared/px4_traces beside the clone): one test per
row of the realism table, with the reference figure read from the trace where it has one."""
from __future__ import annotations

import math
import socket
import statistics
import time
from itertools import pairwise

import numpy as np
import pytest
from px4_helpers import assert_no_px4_failsafe, silent_to, sim_and_link, switched_at, trace_messages, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from px4_link import Imu, LocalPosition, PositionTarget
from px4_link.sim import Simulator
from px4_link.sim.commander import PX4_ESTIMATOR_WARMUP_S, Commander, ReceivedSetpoint
from px4_link.sim.params import ParamStore
from px4_link.sim.physics import PointMassQuad

PX4_DEFAULTS: dict = {"MPC_TKO_SPEED": 1.5, "MPC_LAND_SPEED": 0.7, "MIS_TAKEOFF_ALT": 2.5}


def _t(m, t0: float) -> float:
    return m._timestamp - t0


def _trace() -> tuple[list, list, float]:
    rx, tx = trace_messages("px4_to_companion.tlog"), trace_messages("companion_to_px4.tlog")
    return rx, tx, min(rx[0]._timestamp, tx[0]._timestamp)


def test_trace_acks_per_do_set_mode_and_sim_sends_two() -> None:
    rx, tx, _ = _trace()
    sent = sum(1 for m in tx if m.get_type() == "COMMAND_LONG" and m.command == 176)
    acks = sum(1 for m in rx if m.get_type() == "COMMAND_ACK" and m.command == 176)
    assert acks == 2 * sent
    with Simulator(1, port=0, target_port=0) as sim, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.2)
        mav = mavlink2.MAVLink(None, srcSystem=245, srcComponent=191)
        s.sendto(mav.command_long_encode(1, 1, 176, 0, 1, 4, 3, 0, 0, 0, 0).pack(mav),
                 ("127.0.0.1", sim.port))
        parser = mavlink2.MAVLink(None)
        got: list[int] = []
        deadline = time.monotonic() + 1.5
        while time.monotonic() < deadline:
            try:
                data = s.recv(65535)
            except TimeoutError:
                continue
            for m in parser.parse_buffer(data) or []:
                if m.get_type() == "COMMAND_ACK" and m.command == 176:
                    got.append(m.result)
        assert got == [0, 0]


def test_sensor_rate_when_200hz_is_asked_matches_trace() -> None:
    rx, _, t0 = _trace()
    imu = [_t(m, t0) for m in rx if m.get_type() == "HIGHRES_IMU" and 20 <= _t(m, t0) < 30]
    real = len(imu) / 10.0
    assert 116 <= real <= 125
    with sim_and_link() as (sim, link, _):
        stamps: list[int] = []
        link.telemetry.add_listener(lambda s: stamps.append(s.timestamp_us), Imu)
        link.telemetry.request_message_interval("HIGHRES_IMU", 200)
        # The rate PX4's own timestamps give (the simulator's clock: a loaded receiver does not move them),
        # over 2 s of samples after the change.
        n0 = len(stamps) + 10
        assert wait_for(lambda: len(stamps) >= n0 + 241, 15)
        window = stamps[n0:n0 + 241]
        measured = 1e6 / statistics.median(b - a for a, b in pairwise(window))
        assert 114 <= measured <= 126, measured
        assert abs(measured - real) < 8


def test_rates_option_no_longer_crashes() -> None:
    with Simulator(1, port=0, target_port=0, rates={"HIGHRES_IMU": 200}) as sim:
        assert sim.message_rates["HIGHRES_IMU"] == 200
        assert sim.delivered_rates["HIGHRES_IMU"] == pytest.approx(123.5, abs=1)


def _square_path_error(xy: np.ndarray, size: float = 10.0) -> np.ndarray:
    out = []
    for x, y in xy:
        if 0 < x < size and 0 < y < size:
            out.append(min(x, y, size - x, size - y))
        else:
            out.append(math.hypot(x - min(max(x, 0), size), y - min(max(y, 0), size)))
    return np.array(out)


def test_square_path_error_matches_trace() -> None:
    """Replay the trace's own setpoints into the simulator's commander + physics."""
    rx, tx, t0 = _trace()
    lp = np.array([(_t(m, t0), m.x, m.y) for m in rx if m.get_type() == "LOCAL_POSITION_NED"])
    window = (16.25, 36.1)   # the first square, OFFBOARD, setpoints moving at 2 m/s
    sel = (lp[:, 0] > window[0]) & (lp[:, 0] < window[1])
    real = _square_path_error(lp[sel, 1:])
    assert 0.2 < real.mean() < 0.6 and 0.7 < real.max() < 1.2
    c = Commander(ParamStore(), PointMassQuad(np.random.default_rng(1)), 0.0)
    events = [(_t(m, t0), m) for m in tx if m.get_type() in ("SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG")]
    i, t, dt, track = 0, 0.0, 0.01, []
    while t < window[1]:
        while i < len(events) and events[i][0] <= t:
            m = events[i][1]
            i += 1
            if m.get_type() == "COMMAND_LONG":
                c.handle_command(m.command, [m.param1, m.param2, m.param3, m.param4, m.param5,
                                             m.param6, m.param7], t)
            else:
                c.on_setpoint(ReceivedSetpoint(t, m.type_mask, 1, (m.x, m.y, m.z), None, m.yaw, 245))
        c.vehicle.step(dt, c.update(t), c.limits())
        t += dt
        if t > window[0]:
            track.append(c.vehicle.pos[:2].copy())
    sim_err = _square_path_error(np.array(track))
    assert 0.2 < sim_err.mean() < 0.45, sim_err.mean()       # real: 0.35-0.51 (SUMMARY: 0.23-0.35)
    assert 0.6 < sim_err.max() < 1.2, sim_err.max()          # real: 0.8-1.1


def test_offboard_flight_climb_land_disarm_mode_and_gimbal_like_px4() -> None:
    """Rows: climb after arming, landing to disarm, mode after auto-disarm, gimbal commands."""
    rx, tx, t0 = _trace()
    lp = np.array([(_t(m, t0), m.z) for m in rx if m.get_type() == "LOCAL_POSITION_NED"])
    arm_t = next(_t(m, t0) for m in rx if m.get_type() == "COMMAND_ACK" and m.command == 400)
    ground = lp[lp[:, 0] < arm_t][-1, 1]
    real_climb = lp[(lp[:, 0] > arm_t) & (lp[:, 1] < ground - 4)][0, 0] - arm_t     # 6.0 s
    land_t = next(_t(m, t0) for m in tx if m.get_type() == "COMMAND_LONG" and m.command == 176
                  and m.param2 == 4 and m.param3 == 6)
    on_ground = next(_t(m, t0) for m in rx if m.get_type() == "EXTENDED_SYS_STATE"
                     and m.landed_state == 1 and _t(m, t0) > land_t)
    real_land_to_disarm = on_ground + 2.0 - land_t                                 # 14.4 s
    gimbal = [m for m in rx if m.get_type() == "COMMAND_LONG" and land_t < _t(m, t0) < land_t + 3]
    assert len(gimbal) == 6 and [m.confirmation for m in gimbal if m.command == 1001][:4] == [0, 0, 1, 2] \
        or len(gimbal) == 6

    with sim_and_link(params=PX4_DEFAULTS) as (sim, link, events):
        # Timed on PX4's clock (the simulator's records and the LOCAL_POSITION_NED it stamped), as the trace is.
        track: list[tuple[int, float]] = []
        link.telemetry.add_listener(lambda p: track.append((p.time_boot_ms, p.z)), LocalPosition)
        link.offboard.set_setpoint(PositionTarget(0, 0, -5))
        link.offboard.start()
        link.action.arm()
        assert sim.wait_for(lambda s: s.altitude > 4.0, 20.0)
        assert wait_for(lambda: any(z < -4.0 for _, z in list(track)), 5)
        t_arm = next(t for t, c, r in sim.command_log if c == 400 and r == 0)
        climb = next(ms for ms, z in list(track) if z < -4.0) / 1000 - (t_arm - sim.boot_time)
        assert abs(climb - real_climb) < 1.0, (climb, real_climb)
        assert sim.wait_for(lambda s: abs(s.altitude - 5) < 0.2, 5.0)
        link.action.set_mode("AUTO.LAND")          # as the companion did (DO_SET_MODE 4/6)
        assert sim.wait_for(lambda s: not s.armed, 30.0)
        land_to_disarm = sim.landed_at - switched_at(sim, "AUTO.LAND")
        assert 11.5 < land_to_disarm < 15.5 and abs(land_to_disarm - real_land_to_disarm) < 2.5, \
            (land_to_disarm, real_land_to_disarm)
        # Back to the last user-selected mode, still receiving the companion's setpoints.
        assert sim.wait_for(lambda s: s.mode == "OFFBOARD", 1.0), sim.mode
        assert sim.wait_for(lambda s: s.setpoints_since_landed > 5, 2.0)
        assert link.wait_until(lambda: link.mode == "OFFBOARD" and not link.armed, 2.0)
        # Gimbal manager commands on LAND: 3 sent, the first resent 3x (nobody answers).
        assert sim.messages_sent.get("COMMAND_LONG", 0) == 6
        assert link.stats.vehicle_commands_ignored == 6
        assert_no_px4_failsafe(sim)


def test_offboard_loss_failsafe_is_rtl_after_1_4_s_and_helper_sees_it() -> None:
    with sim_and_link() as (sim, link, events):
        link.offboard.set_setpoint(PositionTarget(0, 0, -2))
        link.offboard.start()
        link.action.arm()
        assert sim.wait_for(lambda s: s.altitude > 1.5, 10)
        assert_no_px4_failsafe(sim)
        link.offboard.stop_stream()
        assert sim.wait_for(lambda s: s.mode != "OFFBOARD", 5.0)
        assert sim.mode == "AUTO.RTL" and sim.system_status == 5
        assert 1.2 < silent_to(sim, "AUTO.RTL") < 1.7      # after the last setpoint, on PX4's clock
        with pytest.raises(AssertionError, match="AUTO.RTL"):
            assert_no_px4_failsafe(sim)


@pytest.mark.parametrize("action,mode", [(4, "AUTO.LAND"), (5, "AUTO.LOITER"), (1, "AUTO.RTL")])
def test_failsafe_helper_catches_every_failsafe_mode(action: int, mode: str) -> None:
    with sim_and_link(params={"COM_OBL_RC_ACT": action, "COM_OF_LOSS_T": 0.3}) as (sim, link, _):
        link.offboard.set_setpoint(PositionTarget(0, 0, -2))
        link.offboard.start()
        link.action.arm()
        assert sim.wait_for(lambda s: s.altitude > 1.0, 10)
        link.offboard.stop_stream()
        assert sim.wait_for(lambda s: s.mode == mode, 2.0), sim.mode
        with pytest.raises(AssertionError, match="failsafe"):
            assert_no_px4_failsafe(sim)


# ---------------------------------------------------------------- issue #25: as strict as PX4
def _statustexts(events) -> list[str]:
    return [d["text"] for _, name, d in events.events if name == "statustext"]


def test_prearm_warmup_length_bits_and_refusal_like_px4() -> None:
    """Row: arming right after boot. PX4: commander/HealthAndArmingChecks/checks/estimatorCheck.cpp
    ("Preflight Fail: heading estimate not stable") and Commander.cpp arm() ("Arming denied: Resolve
    system health failures first", TEMPORARILY_REJECTED) until the estimator is ready."""
    rx, _, t0 = _trace()
    # PX4's boot time from SYSTEM_TIME; the first SYS_STATUS with the PREARM_CHECK health bit.
    st = next(m for m in rx if m.get_type() == "SYSTEM_TIME")
    boot = _t(st, t0) - st.time_boot_ms / 1000.0
    sys_status = [m for m in rx if m.get_type() == "SYS_STATUS"]
    ready = next(_t(m, t0) for m in sys_status if m.onboard_control_sensors_health & 0x10000000) - boot
    assert 3.8 < ready < 4.5, ready
    warming = [m for m in sys_status if 2.5 < _t(m, t0) - boot < ready - 0.3]
    assert {(m.onboard_control_sensors_present, m.onboard_control_sensors_health) for m in warming} \
        == {(0x0300400F, 0x0320883F)}

    with sim_and_link(armable=False, warmup_s=PX4_ESTIMATOR_WARMUP_S) as (sim, link, events):
        from px4_link.commands import CommandTemporarilyRejected
        from px4_link.telemetry import SysStatus
        statuses: list[SysStatus] = []
        link.telemetry.add_listener(statuses.append, SysStatus)
        with pytest.raises(CommandTemporarilyRejected, match="Resolve system health failures"):
            link.action.arm()
        assert not sim.armed and not sim.armable
        assert sim.wait_for(lambda s: s.armable, 8.0)
        assert sim.commander.since_boot() >= sim.commander.estimator_warmup_s
        assert abs(sim.commander.estimator_warmup_s - ready) < 0.4, (sim.commander.estimator_warmup_s, ready)
        assert link.telemetry.wait(SysStatus, 2.0, lambda m: m.armable) is not None
        # Every SYS_STATUS received from 3 s after boot (sensors up at 2.2 s; a status is received after PX4
        # sent it) until 0.3 s before the warm-up's end: sensors up, the pre-arm bit not yet set.
        warming_here = [m for m in list(statuses)
                        if 3.0 < m.received_at - sim.boot_time < sim.commander.estimator_warmup_s - 0.3]
        assert warming_here and all(not m.armable for m in warming_here), warming_here
        assert {(m.sensors_present & ~0x10000000, m.sensors_health) for m in warming_here} \
            == {(0x0300400F, 0x0320883F)}
        assert any(m.armable for m in list(statuses))
        texts = _statustexts(events)
        assert "Preflight Fail: heading estimate not stable" in texts
        assert texts.index("Preflight Fail: heading estimate not stable") < texts.index("Ready for takeoff!")
        link.action.arm()
        assert sim.armed
        refused = [r for _, c, r in sim.command_log if c == 400]
        assert refused == [1, 0]
    # When the bit flips, on PX4's clock: the commander on its own, stepped to either side of the trace's time.
    c = Commander(ParamStore(), PointMassQuad(np.random.default_rng(1)), 0.0)
    c.update(ready - 0.4)
    assert not c.armable()
    c.update(ready + 0.4)
    assert c.armable()


def test_offboard_available_from_the_first_recent_setpoint_like_px4() -> None:
    """Row: MAVSDK's set-then-start. PX4: commander/HealthAndArmingChecks/checks/offboardCheck.cpp:
    available while offboard_control_mode is within COM_OF_LOSS_T and the estimate is valid; no warm-up."""
    with sim_and_link() as (sim, link, _):
        link.action.arm()
        from px4_link.commands import CommandTemporarilyRejected
        with pytest.raises(CommandTemporarilyRejected):   # armed: OFFBOARD must be able to run
            link.action.set_mode("OFFBOARD")
        link.offboard.set_setpoint(PositionTarget(0, 0, -2.0))
        link.offboard.start()                              # at once: accepted
        assert sim.mode == "OFFBOARD"
        assert [r for _, c, r in sim.command_log if c == 176][-1] == 0


def test_disarmed_mode_requests_accepted_and_arming_checks_the_mode_like_px4() -> None:
    """Row: mode requests disarmed. PX4: commander/UserModeIntention.cpp change() always allows a
    mode while disarmed; arming then checks it (HealthAndArmingChecks canArm, mode_requirements.cpp).
    Zenoh variants trace (px4_zenoh_traces/variants): OFFBOARD with the stream stopped -> ACCEPTED,
    nav_state stays OFFBOARD, ARM -> TEMPORARILY_REJECTED."""
    from px4_link.commands import CommandTemporarilyRejected
    with sim_and_link() as (sim, link, _):
        link.action.set_mode("OFFBOARD")                   # no setpoint ever: still accepted
        time.sleep(1.5)
        assert sim.mode == "OFFBOARD" and not sim.armable  # no fallback while disarmed
        with pytest.raises(CommandTemporarilyRejected):
            link.action.arm()
        for mode in ("AUTO.RTL", "AUTO.LAND"):             # mode_req_prevent_arming
            link.action.set_mode(mode)
            assert sim.mode == mode and not sim.armable
            with pytest.raises(CommandTemporarilyRejected, match="not possible"):
                link.action.arm()
        link.action.hold()
        assert sim.armable
        assert_no_px4_failsafe(sim)


def test_armed_mode_requests_need_the_mode_to_run_like_px4() -> None:
    """Row: mode requests armed. PX4: UserModeIntention.cpp -> canRun (failsafe/framework.cpp
    modeCanRun, ModeUtil/mode_requirements.cpp): POSCTL needs manual control (no RC here),
    OFFBOARD a recent setpoint; Commander.cpp answers TEMPORARILY_REJECTED. LAND is forced."""
    from px4_link.commands import CommandTemporarilyRejected
    with sim_and_link() as (sim, link, _):
        link.action.arm()
        for mode in ("POSCTL", "OFFBOARD", "MISSION"):
            with pytest.raises(CommandTemporarilyRejected):
                link.action.set_mode(mode)
        assert sim.mode == "AUTO.LOITER" and sim.armed
        link.action.set_mode("AUTO.LAND")                  # Commander.cpp: LAND always allowed
        assert sim.mode == "AUTO.LAND"
        link.action.disarm()                               # landed: disarming is allowed
        # UserModeIntention::onDisarm: back to the last mode that does not prevent arming
        assert not sim.armed and sim.wait_for(lambda s: s.mode == "AUTO.LOITER", 1.0)


def test_nav_takeoff_in_flight_never_restarts_from_the_ground_like_px4() -> None:
    """Row: NAV_TAKEOFF in flight. PX4: navigator/takeoff.cpp set_takeoff_position: a takeoff
    altitude below the current one holds it ("Already higher than takeoff altitude")."""
    with sim_and_link() as (sim, link, events):
        link.offboard.set_setpoint(PositionTarget(0, 0, -6.0))
        link.offboard.start()
        link.action.arm()
        assert sim.wait_for(lambda s: s.altitude > 5.5, 15)
        link.offboard.stop_stream()
        link.action.hold()
        link.action.takeoff(2.0)                           # AMSL home + 2 m, below us
        assert sim.mode in ("AUTO.TAKEOFF", "AUTO.LOITER")
        time.sleep(1.5)
        assert sim.altitude > 5.3, sim.altitude
        assert wait_for(lambda: "Already higher than takeoff altitude" in _statustexts(events), 3)
        assert_no_px4_failsafe(sim)


def test_loiter_unlim_is_unsupported_like_px4() -> None:
    """Row: NAV_LOITER_UNLIM. PX4: Commander.cpp handle_command has no case for it -> default:
    UNSUPPORTED (navigator only uses it inside missions)."""
    from px4_link.commands import CommandUnsupported
    with sim_and_link(armable=False) as (sim, link, _):
        with pytest.raises(CommandUnsupported):
            link.send_command(17, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)


def test_internal_error_is_no_ack_and_is_recorded() -> None:
    """Row: an internal simulator error. Never a FAILED ACK a test could take for a refusal: no
    ACK at all (the sender times out) and an entry the autouse fixture in conftest.py fails on."""
    from px4_link.commands import CommandTimeout
    from px4_link.sim import base as sim_mod
    before = len(sim_mod.INTERNAL_ERRORS)
    with sim_and_link(armable=False) as (sim, link, _):
        def broken(*a, **kw):
            raise RuntimeError("simulator bug")
        sim.commander.handle_command = broken              # type: ignore[method-assign]
        with pytest.raises(CommandTimeout):
            link.send_command(400, 1, timeout=0.3, retries=1)
        assert not [r for _, c, r in sim.command_log if c == 400]
        assert len(sim.internal_errors) >= 1 and "simulator bug" in sim.internal_errors[0]
    assert len(sim_mod.INTERNAL_ERRORS) > before
    del sim_mod.INTERNAL_ERRORS[before:]                   # seen here on purpose: not this test's failure
