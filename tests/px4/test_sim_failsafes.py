"""The simulator's failsafes against PX4's source: one row per rule of px4_link/sim/failsafe.py, each
flown over real MAVLink/UDP with px4_link, naming the PX4 file it follows."""
from __future__ import annotations

import time

import pytest
from px4_helpers import gcs_heartbeats, silent_to, sim_and_link, switched_at, wait_for

from px4_link import PositionTarget
from px4_link.sim import Simulator
from px4_link.sim.failsafe import battery_action, battery_warning, gf_action, offboard_loss_action
from px4_link.sim.faults import EkfReset, EstimateLoss, LowBattery
from px4_link.sim.params import ParamStore
from px4_link.telemetry import LocalPosition, SysStatus

QUICK = {"estimator_warmup_s": 0.5}   # arming is not what these rows test


def _north(link) -> float:
    lp = link.telemetry.latest(LocalPosition)
    return float("nan") if lp is None else lp.x


def _battery_pct(link) -> float:
    st = link.telemetry.latest(SysStatus)
    return float("nan") if st is None else st.battery_remaining_pct


def _airborne(sim: Simulator, link, alt: float = 2.0) -> None:
    assert wait_for(lambda: sim.armable, 10)
    link.action.arm()
    link.action.takeoff(alt)
    assert wait_for(lambda: sim.mode == "AUTO.LOITER" and sim.altitude > alt * 0.8, 20), (sim.mode, sim.altitude)


def _offboard(sim: Simulator, link, target: PositionTarget) -> None:
    link.offboard.set_setpoint(target)
    link.offboard.start()
    assert wait_for(lambda: sim.mode == "OFFBOARD", 5)


def _texts(events) -> list[str]:
    return [d["text"] for _, n, d in events.events if n == "statustext"]


def _modes(sim: Simulator) -> list[tuple[str, str]]:
    return [(c.new, c.reason) for c in sim.mode_log]


# ---------------------------------------------------------------- PX4's defaults
@pytest.mark.fast
def test_defaults_are_px4s() -> None:
    """commander_params.c, navigator/geofence_params.c, lib/battery/module.yaml (SITL: COM_RC_IN_MODE 1)."""
    p = ParamStore()
    assert (p["GF_ACTION"], p["GF_MAX_HOR_DIST"], p["GF_MAX_VER_DIST"]) == (2, 0.0, 0.0)
    assert (p["BAT_LOW_THR"], p["BAT_CRIT_THR"], p["BAT_EMERGEN_THR"], p["COM_LOW_BAT_ACT"]) == \
        pytest.approx((0.15, 0.07, 0.05, 0))
    assert (p["COM_DL_LOSS_T"], p["NAV_DLL_ACT"], p["NAV_RCL_ACT"], p["COM_RC_IN_MODE"]) == (10, 0, 2, 1)
    # failsafe.cpp's tables
    assert [gf_action(v) for v in range(6)] == ["none", "warn", "hold", "rtl", "terminate", "land"]
    assert battery_warning(0.149, p) == 1 and battery_warning(0.069, p) == 2 and battery_warning(0.049, p) == 3
    assert battery_warning(0.15, p) == 0   # battery.cpp: strictly below
    assert [battery_action(0, w) for w in (1, 2, 3)] == ["warn", "warn", "warn"]
    assert [battery_action(2, w) for w in (1, 2, 3)] == ["warn", "land", "land"]
    assert [battery_action(3, w) for w in (1, 2, 3)] == ["warn", "rtl", "land"]
    assert offboard_loss_action(p) == "AUTO.RTL"   # COM_OBL_RC_ACT 0 needs RC -> NAV_RCL_ACT 2


# ---------------------------------------------------------------- geofence
def test_geofence_off_by_default_then_gf_max_hor_dist_holds_at_once() -> None:
    """navigator/geofence.cpp (GF_MAX_HOR_DIST from home, 0 = off), geofenceCheck.cpp (text),
    failsafe.cpp fromGfActParam (GF_ACTION 2 Hold: takeover by mode switch only, so no COM_FAIL_ACT_T)."""
    with sim_and_link(sim_kwargs=QUICK) as (sim, link, events):
        _airborne(sim, link)
        _offboard(sim, link, PositionTarget(7.0, 0.0, -2.0, yaw=0.0))
        assert wait_for(lambda: sim.position[0] > 6.0, 15)
        assert sim.mode == "OFFBOARD" and not sim.failsafe_log     # 0 = off, as PX4 ships
        sim.set_param("GF_MAX_HOR_DIST", 10.0)
        link.offboard.set_setpoint(PositionTarget(15.0, 0.0, -2.0, yaw=0.0))
        assert wait_for(lambda: sim.mode == "AUTO.LOITER", 15), sim.mode
        ev = sim.failsafe_log[-1]
        assert (ev.cause, ev.action) == ("geofence breach", "AUTO.LOITER")
        assert 10.0 <= sim.position[0] < 14.0   # stopped at the fence, braking distance beyond it
        assert wait_for(lambda: "Geofence: exceeding maximum distance to Home" in _texts(events), 2)


def test_geofence_return_waits_com_fail_act_t_in_hold() -> None:
    """failsafe/framework.cpp: RTL (takeover "Auto") is preceded by COM_FAIL_ACT_T of Hold;
    GF_MAX_VER_DIST is the height above home (geofence.cpp)."""
    with sim_and_link(params={"GF_MAX_VER_DIST": 4.0, "GF_ACTION": 3, "COM_FAIL_ACT_T": 1.0},
                      sim_kwargs=QUICK) as (sim, link, events):
        _airborne(sim, link)
        _offboard(sim, link, PositionTarget(0.0, 0.0, -8.0, yaw=0.0))
        assert wait_for(lambda: sim.mode == "AUTO.LOITER", 15), sim.mode
        assert sim.altitude >= 4.0
        assert wait_for(lambda: sim.mode == "AUTO.RTL", 5)
        # COM_FAIL_ACT_T of Hold before the Return, on PX4's clock (the simulator's mode log).
        t_rtl = switched_at(sim, "AUTO.RTL")
        t_hold = max(c.time for c in sim.mode_log if c.new == "AUTO.LOITER" and c.time <= t_rtl)
        assert 0.8 <= t_rtl - t_hold <= 1.5, t_rtl - t_hold
        assert wait_for(lambda: "Geofence: exceeding maximum altitude above Home" in _texts(events), 2)
        assert wait_for(lambda: "Failsafe activated: entering Hold for 1 seconds" in _texts(events), 2)


# ---------------------------------------------------------------- battery
def test_low_battery_warns_and_critical_lands_with_com_low_bat_act_2() -> None:
    """lib/battery/battery.cpp determineWarning, batteryCheck.cpp (texts), failsafe.cpp
    fromBatteryWarningActParam: low only warns; critical with COM_LOW_BAT_ACT 2 lands."""
    with sim_and_link(params={"COM_LOW_BAT_ACT": 2, "COM_FAIL_ACT_T": 0.0}, sim_kwargs=QUICK) as (sim, link, events):
        _airborne(sim, link)
        sim.inject(LowBattery(0.0, 0.12))
        assert wait_for(lambda: "Low battery" in _texts(events), 3)
        time.sleep(0.5)
        assert sim.mode == "AUTO.LOITER" and not sim.failsafe_log
        assert wait_for(lambda: _battery_pct(link) == 12, 3), _battery_pct(link)   # SYS_STATUS, 5 Hz
        sim.inject(LowBattery(0.0, 0.06))
        assert wait_for(lambda: sim.mode == "AUTO.LAND", 3)
        assert (sim.failsafe_log[-1].cause, sim.failsafe_log[-1].action) == ("battery critical", "AUTO.LAND")
        assert wait_for(lambda: "Critical battery" in _texts(events), 3), _texts(events)   # follows the switch


def test_critical_battery_only_warns_with_px4s_default() -> None:
    """COM_LOW_BAT_ACT 0 (commander_params.c): "Warning" at every level."""
    with sim_and_link(sim_kwargs=QUICK) as (sim, link, events):
        _airborne(sim, link)
        sim.inject(LowBattery(0.0, 0.04))
        assert wait_for(lambda: "Emergency battery level" in _texts(events), 3)
        time.sleep(0.5)
        assert sim.mode == "AUTO.LOITER" and not sim.failsafe_log


# ---------------------------------------------------------------- GCS link (NAV_DLL_ACT)
def test_gcs_loss_returns_after_com_dl_loss_t_and_only_gcs_heartbeats_count() -> None:
    """mavlink_receiver.cpp (MAV_TYPE_GCS heartbeats, 2.5 s timeout checked every 1.25 s),
    Commander.cpp (COM_DL_LOSS_T), failsafe.cpp (NAV_DLL_ACT 2 Return)."""
    with sim_and_link(params={"NAV_DLL_ACT": 2, "COM_DL_LOSS_T": 5, "COM_FAIL_ACT_T": 0.0},
                      sim_kwargs=QUICK, armable=False) as (sim, link, events):
        # The simulator answers the first address it hears (as PX4's UDP link): px4_link's.
        assert wait_for(lambda: sim.protocol is not None and sim.protocol.stats.messages_received > 0, 5)
        time.sleep(1.5)   # px4_link's own heartbeats flow meanwhile
        assert sim.gcs_connection_lost, "the companion's ONBOARD_CONTROLLER heartbeats counted as a GCS"
        # rcAndDataLinkCheck.cpp: with NAV_DLL_ACT set, no arming without a GCS
        assert wait_for(lambda: sim.commander.arming_refusal() == "Preflight Fail: No connection to the GCS", 10), \
            sim.commander.arming_refusal()
        assert not sim.armable
        with gcs_heartbeats(sim.port) as stop:
            assert wait_for(lambda: not sim.gcs_connection_lost, 3)
            _airborne(sim, link)
            stop.set()
            t_last = time.monotonic()
            assert wait_for(lambda: sim.mode == "AUTO.RTL", 15), sim.mode
            silent = switched_at(sim, "AUTO.RTL", t_last) - t_last   # the switch on PX4's clock
        # COM_DL_LOSS_T after the last check that saw a heartbeat: 5 + (1.25 .. 2.5) s
        assert 5.0 + 1.0 <= silent <= 5.0 + 2.5 + 1.0 + 0.5, silent
        assert (sim.failsafe_log[-1].cause, sim.failsafe_log[-1].action) == ("GCS connection loss", "AUTO.RTL")
        # PX4's STATUSTEXT follows the switch over the link: waited for, not raced (a loaded machine lags it)
        assert wait_for(lambda: "Connection to ground station lost" in _texts(events), 5), _texts(events)


# ---------------------------------------------------------------- RC and offboard loss
def test_offboard_loss_falls_back_to_nav_rcl_act_without_rc_and_follows_com_of_loss_t() -> None:
    """failsafe.cpp checkModeFallback: COM_OBL_RC_ACT 0 (Position) needs manual control, so
    NAV_RCL_ACT decides (3 = Land here); offboardCheck.cpp: COM_OF_LOSS_T. RC loss itself never
    fires: lost at arming, it is ignored for the flight (checkStateAndMode)."""
    with sim_and_link(params={"NAV_RCL_ACT": 3, "COM_OF_LOSS_T": 2.0}, sim_kwargs=QUICK) as (sim, link, _):
        _airborne(sim, link)
        time.sleep(1.0)
        assert not sim.failsafe_log, "an RC loss failsafe fired without RC"
        _offboard(sim, link, PositionTarget(0.0, 0.0, -2.0, yaw=0.0))
        link.offboard.stop_stream()
        assert wait_for(lambda: sim.mode == "AUTO.LAND", 8), sim.mode
        assert 2.0 <= silent_to(sim, "AUTO.LAND") <= 3.2      # after the last setpoint, on PX4's clock
        assert (sim.failsafe_log[-1].cause, sim.failsafe_log[-1].action) == ("offboard loss", "AUTO.LAND")


# ---------------------------------------------------------------- estimate loss and EKF reset
def test_estimate_loss_in_offboard_descends_at_once_and_clears_with_the_estimate() -> None:
    """offboardCheck.cpp (position offboard needs a local position), mode_requirements.cpp and
    framework.cpp's fallbacks (RTL, Land need a position: Descend, reported as AUTO.LAND by
    px4_custom_mode.h), no COM_FAIL_ACT_T for a mode fallback."""
    with sim_and_link(sim_kwargs=QUICK) as (sim, link, _):
        _airborne(sim, link, 3.0)
        _offboard(sim, link, PositionTarget(0.0, 0.0, -3.0, yaw=0.0))
        sim.inject(EstimateLoss(0.0, 2.0))
        assert wait_for(lambda: sim.mode == "AUTO.LAND", 3.0), sim.mode
        t_lost = next(t for t, step in sim.faults_applied if isinstance(step, EstimateLoss))
        assert switched_at(sim, "AUTO.LAND", t_lost) - t_lost < 0.5   # at once, on PX4's clock
        assert sim.failsafe_log[-1].cause == "estimate loss"
        alt = sim.altitude
        # The estimate is back after 2 s: the fallback clears; px4_link stopped streaming on the
        # failsafe, so OFFBOARD cannot run and the offboard loss action (Return) follows.
        assert wait_for(lambda: sim.mode != "AUTO.LAND", 4), sim.mode
        assert sim.altitude < alt and sim.mode in ("OFFBOARD", "AUTO.RTL"), (sim.altitude, sim.mode)


def test_ekf_reset_jumps_local_position_and_a_holding_vehicle_stays_put() -> None:
    """An estimator reset: LOCAL_POSITION_NED jumps (EKF2 bumps xy_reset_counter; MAVLink carries only
    the jump), and flight tasks shift their hold setpoint (FlightTask::_checkEkfResetCounters)."""
    with sim_and_link(sim_kwargs=QUICK) as (sim, link, _):
        _airborne(sim, link)
        x0 = _north(link)
        sim.inject(EkfReset(0.0, (12.0, 0.0, 0.0)))
        assert wait_for(lambda: _north(link) > x0 + 11.0, 2), _north(link)
        time.sleep(2.0)
        assert abs(_north(link) - (x0 + 12.0)) < 0.5, "flew back to the pre-reset setpoint"
        assert sim.mode == "AUTO.LOITER" and not sim.failsafe_log


@pytest.mark.fast
def test_cli_fault_flags_parse() -> None:
    from px4_link.sim.cli import build_parser

    a = build_parser().parse_args(["--estimate-loss", "10:3", "--ekf-reset", "5:2,1", "--low-battery", "20:0.1"])
    assert a.estimate_loss == [EstimateLoss(10.0, 3.0)]
    assert a.ekf_reset == [EkfReset(5.0, (2.0, 1.0, 0.0))]
    assert a.low_battery == [LowBattery(20.0, 0.1)]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--low-battery", "1:2"])
