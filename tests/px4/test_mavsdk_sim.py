"""A standard MAVLink SDK (MAVSDK-Python, gRPC wrapper with mavsdk_server) flies the
simulator as it would fly PX4: health, arm, offboard position, land. Loopback only.

MAVSDK's documented offboard start is ``set_position_ned`` then ``offboard.start()`` at once; real
PX4 SITL starts OFFBOARD on it (commander/HealthAndArmingChecks/checks/offboardCheck.cpp: a setpoint
within COM_OF_LOSS_T is enough, no warm-up), so the simulator must too: no sleep in between."""
from __future__ import annotations

import asyncio
import warnings

from conftest import free_port

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    from mavsdk import System
    from mavsdk.offboard import PositionNedYaw

from px4_link.sim import Simulator


async def _fly(udp_port: int, grpc_port: int, sim: Simulator) -> None:
    drone = System(port=grpc_port)
    await drone.connect(system_address=f"udpin://127.0.0.1:{udp_port}")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_armable and health.is_global_position_ok:
            break
    await drone.action.arm()
    # MAVSDK's documented way, exactly: set, then start at once (no sleep PX4 does not need).
    await drone.offboard.set_position_ned(PositionNedYaw(2.0, 1.0, -3.0, 0.0))
    await drone.offboard.start()
    async for pos in drone.telemetry.position_velocity_ned():
        p = pos.position
        if abs(p.north_m - 2) < 0.3 and abs(p.east_m - 1) < 0.3 and abs(p.down_m + 3) < 0.3:
            break
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break
    async for armed in drone.telemetry.armed():
        if not armed:
            break
    drone._stop_mavsdk_server()


def test_mavsdk_set_position_then_offboard_start_at_once_flies_and_lands() -> None:
    udp_port, grpc_port = free_port(), free_port()    # below the ephemeral range (conftest)
    params = {"MPC_LAND_SPEED": 2.0, "MPC_TKO_SPEED": 3.0}
    with Simulator(1, port=0, target_port=udp_port, params=params) as sim:
        asyncio.run(asyncio.wait_for(_fly(udp_port, grpc_port, sim), timeout=55))
        assert not sim.armed and sim.landed
        assert "OFFBOARD" in [c.new for c in sim.mode_log]
        # offboard.start() right after the first set_position_ned: accepted the first time.
        assert [r for _, c, r in sim.command_log if c == 176][:1] == [0]
