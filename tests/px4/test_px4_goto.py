"""MAV_CMD_DO_REPOSITION (``Action.goto_location``) against the simulator, with PX4's rules
(Commander.cpp: exactly the change-mode flag, then Hold; navigator_main.cpp: flown only when armed,
never outside the geofence)."""
from __future__ import annotations

import math

import pytest
from px4_helpers import sim_and_link, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from px4_link import GlobalPosition, Px4Link
from px4_link.commands import CommandUnsupported


def _offset(gp: GlobalPosition, north: float, east: float) -> tuple[float, float]:
    lat = gp.lat_deg + math.degrees(north / 6378137.0)
    lon = gp.lon_deg + math.degrees(east / (6378137.0 * math.cos(math.radians(gp.lat_deg))))
    return lat, lon


def _global(link: Px4Link) -> GlobalPosition:
    assert wait_for(lambda: link.telemetry.latest(GlobalPosition) is not None, 5)
    gp = link.telemetry.latest(GlobalPosition)
    assert gp is not None
    return gp


def test_goto_flies_to_the_point_in_hold_and_stays() -> None:
    with sim_and_link() as (sim, link, _):
        link.action.arm()
        link.action.takeoff(3.0)
        assert sim.wait_for(lambda s: s.altitude > 2.6 and s.mode == "AUTO.LOITER", 15), (sim.position, sim.mode)
        gp = _global(link)
        north0, east0 = float(sim.position[0]), float(sim.position[1])
        lat, lon = _offset(gp, 12.0, -6.0)
        home_amsl = gp.alt_m - gp.relative_alt_m
        link.action.goto_location(lat, lon, home_amsl + 5.0)
        assert sim.mode == "AUTO.LOITER"
        ok = sim.wait_for(lambda s: math.dist((s.position[0] - north0, s.position[1] - east0), (12.0, -6.0)) < 0.6
                          and abs(s.altitude - 5.0) < 0.4, 20)
        assert ok, (sim.position, sim.altitude)


def test_goto_refusals_as_px4() -> None:
    with sim_and_link(params={"GF_MAX_HOR_DIST": 50.0, "GF_ACTION": 2}) as (sim, link, events):
        gp = _global(link)
        # Any flag but MAV_DO_REPOSITION_FLAGS_CHANGE_MODE: UNSUPPORTED (Commander.cpp).
        with pytest.raises(CommandUnsupported):
            link.send_command(mavlink2.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, gp.lat_deg, gp.lon_deg, gp.alt_m)
        # Disarmed: ACCEPTED (Hold), but the navigator keeps still.
        lat, lon = _offset(gp, 10.0, 0.0)
        link.action.goto_location(lat, lon, gp.alt_m + 5)
        link.action.arm()
        link.action.takeoff(3.0)
        assert sim.wait_for(lambda s: s.altitude > 2.6 and s.mode == "AUTO.LOITER", 15), (sim.position, sim.mode)
        assert math.hypot(sim.position[0], sim.position[1]) < 1.0
        # Outside the 50 m fence: ACCEPTED, then "Reposition is outside geofence", and no move.
        far_lat, far_lon = _offset(gp, 80.0, 0.0)
        link.action.goto_location(far_lat, far_lon, gp.alt_m + 3)
        said = lambda: any(n == "statustext" and d["text"] == "Reposition is outside geofence"  # noqa: E731
                           for _, n, d in list(events.events))
        assert wait_for(said, 5), events.names()
        assert not sim.wait_for(lambda s: math.hypot(s.position[0], s.position[1]) > 2.0, 2.0)
