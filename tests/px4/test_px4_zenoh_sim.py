"""The Zenoh simulator flown over raw zenoh-python, as the traces' Python flight flew PX4 SITL:
keys from PX4's tokens, 20 Hz offboard_control_mode + trajectory_setpoint, vehicle_command, ACKs
and vehicle_status read back. Real router, real client sessions, real CDR bytes."""
from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from px4_zenoh_probe import Probe, probed_sim

from px4_zenoh.sim import ZenohSimulator

ACCEPTED, TEMPORARILY_REJECTED, UNSUPPORTED = 0, 1, 3
DO_SET_MODE, ARM, NAV_LAND = 176, 400, 21
OFFBOARD, AUTO_LOITER = 14, 4


@pytest.fixture
def px4() -> Iterator[tuple[Probe, ZenohSimulator]]:
    with probed_sim(estimator_warmup_s=1.0, seed=3, params={"MPC_LAND_SPEED": 1.5, "COM_DISARM_LAND": 1.0}) as pair:
        yield pair


def test_flight_stream_mode_arm_climb_land_disarm(px4: tuple[Probe, ZenohSimulator]) -> None:
    probe, sim = px4
    t0 = time.monotonic()
    probe.start_stream((0.0, 0.0, -2.0))
    assert probe.wait("failsafe_flags", lambda m: not m.offboard_control_signal_lost, 3.0, t0) is not None
    t = probe.command(DO_SET_MODE, 1, 6)
    got = probe.ack(DO_SET_MODE, t)
    assert got is not None and got[1].result == ACCEPTED
    assert (got[1].target_system, got[1].target_component, got[1].from_external) == (1, 1, False)
    assert probe.wait("vehicle_status", lambda m: m.nav_state == OFFBOARD, 2.0, t) is not None
    t = probe.command(ARM, 1)
    got = probe.ack(ARM, t)
    assert got is not None and got[1].result == ACCEPTED
    assert probe.wait("vehicle_status", lambda m: m.arming_state == 2, 2.0, t) is not None
    assert probe.wait("vehicle_local_position", lambda m: m.z < -1.8, 15.0, t) is not None
    assert sim.altitude > 1.5 and sim.mode == "OFFBOARD"
    t = probe.command(NAV_LAND)
    got = probe.ack(NAV_LAND, t)
    assert got is not None and got[1].result == ACCEPTED
    assert probe.wait("vehicle_status", lambda m: m.nav_state == 18, 2.0, t) is not None
    probe.stop_stream()
    landed = probe.wait("vehicle_land_detected", lambda m: m.landed, 15.0, t)
    assert landed is not None
    disarmed = probe.wait("vehicle_status", lambda m: m.arming_state == 1, 10.0, landed[0])
    assert disarmed is not None
    status = disarmed[1]
    # PX4 (and the MAVLink simulator) return to the user's intention, OFFBOARD, once disarmed
    reason_landing = 6
    assert (status.nav_state, status.nav_state_user_intention, status.latest_disarming_reason) == \
        (OFFBOARD, OFFBOARD, reason_landing)
    assert sim.setpoints_received > 20 and not sim.failsafe_log


def test_refusals_and_dropped_inputs(px4: tuple[Probe, ZenohSimulator]) -> None:
    probe, sim = px4
    # another system: dropped silently (no ACK, mode unchanged)
    t = probe.command(DO_SET_MODE, 1, 4, 3, target_system=2)
    assert probe.ack(DO_SET_MODE, t, timeout=1.0) is None
    assert sim.dropped["target"] == 1
    # broadcast ids: ACKed to the command's source ids
    t = probe.command(DO_SET_MODE, 1, 4, 3, target_system=0, target_component=0, source_system=7,
                      source_component=190)
    got = probe.ack(DO_SET_MODE, t)
    assert got is not None and (got[1].result, got[1].target_system, got[1].target_component) == (ACCEPTED, 7, 190)
    # OFFBOARD with no stream: accepted while disarmed, then arming refused
    t = probe.command(DO_SET_MODE, 1, 6)
    got = probe.ack(DO_SET_MODE, t)
    assert got is not None and got[1].result == ACCEPTED
    assert probe.wait("vehicle_status", lambda m: m.nav_state == OFFBOARD, 2.0, t) is not None
    t = probe.command(ARM, 1)
    got = probe.ack(ARM, t)
    assert got is not None and got[1].result == TEMPORARILY_REJECTED and not sim.armed
    # over zenoh-pico's 512 B: dropped before decoding; trailing bytes within it: accepted
    t = probe.command(DO_SET_MODE, 1, 4, 3, extra=bytes(600))
    assert probe.ack(DO_SET_MODE, t, timeout=1.0) is None and sim.dropped["oversize"] == 1
    t = probe.command(DO_SET_MODE, 1, 4, 3, extra=bytes(24), attachment=False)
    got = probe.ack(DO_SET_MODE, t)
    assert got is not None and got[1].result == ACCEPTED
    t = probe.command(31000)
    got = probe.ack(31000, t)
    assert got is not None and got[1].result == UNSUPPORTED


def test_client_retries_until_a_router_is_there() -> None:
    from px4_zenoh_probe import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sim = ZenohSimulator(endpoint, retry_s=0.3).start()
    try:
        time.sleep(1.0)
        assert not sim.connected and sim.connect_attempts >= 2
        probe = Probe(endpoint)
        try:
            assert sim.wait_connected(5.0)
            assert probe.wait("vehicle_status", lambda m: True, 5.0) is not None
        finally:
            probe.close()
    finally:
        sim.stop()
