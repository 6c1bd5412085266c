"""The companion's reaction to each fault the simulator injects, in-process with real parts: the
simulator over real MAVLink/UDP, px4_link, the Companion and a GCS-side peer on real Zenoh sessions."""
from __future__ import annotations

import math
import time

from conftest import wait_for
from px4_helpers import gcs_heartbeats
from rigs import Rig, rig
from rigs import take_off as _lifecycle_take_off

from px4_link.sim.faults import EkfReset, EstimateLoss, LowBattery


def _take_off(r: Rig, alt: float) -> None:
    # PX4's estimator warm-up (sim/commander.py): arm once the pre-arm checks pass, as a GCS does.
    assert wait_for(lambda: r.sim.armable and r.op.state is not None
                    and all(math.isfinite(v) for v in r.op.state.position), 15), "never armable"
    _lifecycle_take_off(r, alt)   # waits for a setpoint the companion accepted (it needs LOCAL_POSITION_NED)


def _lost_to(r: Rig, mode: str) -> bool:
    return any(e.kind == "offboard_lost" and mode in e.detail for e in r.op.events)


def test_estimate_lost_in_offboard_px4_descends_and_the_companion_reports_it(ns: str) -> None:
    with rig(ns) as r:
        _take_off(r, 3.0)
        r.sim.inject(EstimateLoss(0.0, 30.0))
        assert wait_for(lambda: r.sim.mode == "AUTO.LAND", 2), r.sim.mode
        assert wait_for(lambda: _lost_to(r, "AUTO.LAND"), 5), r.op.kinds()
        assert wait_for(lambda: r.companion.lifecycle.state.value != "active", 5)
        assert wait_for(lambda: not r.link.offboard.streaming, 5)


def test_ekf_reset_jump_is_refused_then_a_rebased_target_is_flown(ns: str) -> None:
    with rig(ns) as r:
        _take_off(r, 3.0)
        r.op.target = (0.0, 0.0, -3.0)
        time.sleep(1.0)
        r.sim.inject(EkfReset(0.0, (25.0, 0.0, 0.0)))
        # The GCS still streams in the old frame: 25 m from where PX4 now says the drone is.
        assert wait_for(lambda: any(e.kind == "setpoint_rejected" and "jump" in e.detail
                                    for e in r.op.events if e.client_id == "op"), 5), r.op.kinds()
        assert wait_for(lambda: r.op.state is not None and r.op.state.position[0] > 20.0, 5)
        # Re-based on the reported position, the same hover is accepted again.
        x, y, z = r.op.state.position
        r.op.target = (x, y, z)
        n = len([e for e in r.op.events if e.kind == "setpoint_rejected"])
        if r.sim.mode != "OFFBOARD":   # the companion held while nothing it could forward arrived
            time.sleep(0.5)
            res = r.op.command("offboard_start")
            assert res.success, res.message
        assert wait_for(lambda: r.sim.mode == "OFFBOARD", 5), r.sim.mode
        assert wait_for(lambda: math.dist(r.sim.position, (x, y, z)) < 1.0, 8), r.sim.position
        assert len([e for e in r.op.events if e.kind == "setpoint_rejected"]) <= n + 1


def test_low_battery_px4_returns_and_the_companion_reports_level_and_mode(ns: str) -> None:
    with rig(ns) as r:
        r.sim.set_param("COM_LOW_BAT_ACT", 3)
        r.sim.set_param("COM_FAIL_ACT_T", 1.0)
        _take_off(r, 3.0)
        r.sim.inject(LowBattery(0.0, 0.06))
        assert wait_for(lambda: r.sim.mode == "AUTO.LOITER", 2), r.sim.mode    # COM_FAIL_ACT_T's hold
        assert wait_for(lambda: r.sim.mode == "AUTO.RTL", 3), r.sim.mode
        assert wait_for(lambda: _lost_to(r, "AUTO.LOITER"), 5), r.op.kinds()
        assert wait_for(lambda: r.op.state is not None and abs(r.op.state.battery_remaining - 0.06) < 0.011, 5), \
            r.op.state.battery_remaining if r.op.state else None


def test_geofence_breach_px4_holds_and_the_companion_reports_it(ns: str) -> None:
    with rig(ns) as r:
        r.sim.set_param("GF_MAX_HOR_DIST", 6.0)
        _take_off(r, 3.0)
        r.op.target = (9.0, 0.0, -3.0)   # inside the companion's own fence, outside PX4's
        assert wait_for(lambda: r.sim.mode == "AUTO.LOITER", 15), r.sim.mode
        assert r.sim.failsafe_log[-1].cause == "geofence breach"
        assert wait_for(lambda: _lost_to(r, "AUTO.LOITER"), 5), r.op.kinds()


def test_gcs_link_loss_px4_lands_by_nav_dll_act_and_the_companion_reports_it(ns: str) -> None:
    with rig(ns) as r:
        for name, value in (("NAV_DLL_ACT", 3), ("COM_DL_LOSS_T", 5), ("COM_FAIL_ACT_T", 0.0)):
            r.sim.set_param(name, value)
        # The simulator answers the first address it hears (as PX4's UDP link): the companion's.
        assert wait_for(lambda: r.sim.protocol is not None and r.sim.protocol.stats.messages_received > 0, 5)
        with gcs_heartbeats(r.sim.port) as stop:
            assert wait_for(lambda: not r.sim.gcs_connection_lost, 3)
            _take_off(r, 3.0)
            stop.set()   # QGC's link dies; the companion's own link to PX4 is fine
            assert wait_for(lambda: r.sim.mode == "AUTO.LAND", 12), r.sim.mode
        assert r.sim.failsafe_log[-1].cause == "GCS connection loss"
        assert wait_for(lambda: _lost_to(r, "AUTO.LAND"), 5), r.op.kinds()
