"""Both simulators are one vehicle (px4_link.sim.base.SimulatorBase) behind two front ends: what the
MAVLink simulator could do to its vehicle (scheduled and injected faults, the introspection tests read),
PX4's-Zenoh simulator does too, seen over a real router in PX4's own uORB samples."""
from __future__ import annotations

import time

from px4_zenoh_probe import probed_sim

from px4_link.sim import Simulator
from px4_link.sim.base import SimulatorBase
from px4_link.sim.faults import EstimateLoss, LowBattery
from px4_zenoh.sim import ZenohSimulator

WARNING_NONE = 0


def test_an_injected_low_battery_reaches_px4s_zenoh_samples() -> None:
    with probed_sim(estimator_warmup_s=1.0, seed=5) as (probe, sim):
        t0 = time.monotonic()
        assert probe.wait("failsafe_flags", lambda m: m.battery_warning == WARNING_NONE, 3.0, t0) is not None
        sim.inject(LowBattery(at=0.0, level=0.08))
        t = time.monotonic()
        flags = probe.wait("failsafe_flags", lambda m: m.battery_warning > WARNING_NONE, 3.0, t)
        assert flags is not None
        assert [type(s) for _, s in sim.faults_applied] == [LowBattery]
        assert sim.battery_remaining < 0.1


def test_a_scheduled_estimate_loss_invalidates_then_restores_the_zenoh_local_position() -> None:
    with probed_sim(estimator_warmup_s=1.0, seed=6, faults=[EstimateLoss(at=1.5, duration=1.0)]) as (probe, sim):
        t0 = time.monotonic()
        lost = probe.wait("vehicle_local_position", lambda m: not m.xy_valid, 6.0, t0)
        assert lost is not None
        back = probe.wait("vehicle_local_position", lambda m: m.xy_valid, 4.0, lost[0])
        assert back is not None
        flags = probe.wait("failsafe_flags", lambda m: not m.local_position_invalid, 2.0, back[0])
        assert flags is not None
        assert [type(s).__name__ for _, s in sim.faults_applied] == ["EstimateLoss", "EstimateRestored"]


def test_both_simulators_share_one_vehicle_implementation() -> None:
    # Each inspection property is defined once, on the base: neither front end redefines it.
    shared = ("mode", "armed", "armable", "landed", "landed_state", "position", "velocity", "altitude",
              "setpoints_received", "last_setpoint", "setpoint_arrivals", "failsafe_log", "mode_log",
              "command_log", "landed_at", "setpoints_since_landed", "battery_remaining", "faults_applied",
              "get_param", "set_param", "wait_for", "inject", "start", "stop", "run_forever")
    for cls in (Simulator, ZenohSimulator):
        assert issubclass(cls, SimulatorBase)
        assert not [n for n in shared if n in vars(cls)], cls
    with Simulator(port=0, target_port=0, seed=1, estimator_warmup_s=0.2) as sim:
        sim.set_param("COM_DISARM_LAND", 3.0)
        assert sim.get_param("COM_DISARM_LAND") == 3.0
        assert sim.wait_for(lambda s: s.armable, 5.0)
        assert sim.landed and not sim.armed and sim.command_log == [] and sim.setpoint_arrivals == []
