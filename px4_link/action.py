"""``link.action``: arm, disarm, takeoff, land, hold, return, mode changes (MAVSDK's Action)."""
from __future__ import annotations

import math

from .commands import CommandAck, CommandError, CommandFailed
from .modes import mode_to_main_sub, normalize_mode_name
from .plugin import Core
from .telemetry import GlobalPosition
from .wire import mavlink2

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
ARM_FORCE_MAGIC = 21196  # PX4: param2 == 21196 skips arming/disarming checks

ActionError = CommandError   # MAVSDK-style name; every subclass tells which refusal it was


def set_mode(core: Core, name: str, confirm_timeout: float = 3.0) -> CommandAck:
    """MAV_CMD_DO_SET_MODE with PX4 custom main/sub mode, then wait until the heartbeat shows it, or the
    external mode replacing it (an ACK alone does not guarantee the switch stuck). A function, not only a
    method, because the offboard plugin switches modes too and plugins share only the core."""
    canonical = normalize_mode_name(name)
    main, sub = mode_to_main_sub(canonical)
    ack = core.send_command(mavlink2.MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                            main, sub)
    # A mode replaced by an external one (a companion's RTL) is flown as that one: PX4 shows its nav_state.
    if confirm_timeout > 0 and not core.wait_until(lambda: canonical in (core.state.mode, core.state.mode_replaces),
                                                   confirm_timeout):
        raise CommandFailed(mavlink2.MAV_CMD_DO_SET_MODE, ack.result,
                            f"mode {canonical} accepted but heartbeat still shows "
                            f"{core.state.mode} after {confirm_timeout:g} s")
    return ack


class Action:
    def __init__(self, core: Core) -> None:
        self._core = core

    def arm(self) -> CommandAck:
        return self._core.send_command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def disarm(self, force: bool = False) -> CommandAck:
        """PX4 refuses in the air unless ``force`` (motors stop: the vehicle falls)."""
        return self._core.send_command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                       ARM_FORCE_MAGIC if force else 0)

    def set_mode(self, name: str, confirm_timeout: float = 3.0) -> CommandAck:
        """See ``set_mode``: the ACK and the heartbeat showing the new mode."""
        return set_mode(self._core, name, confirm_timeout)

    def takeoff(self, altitude: float | None = None) -> CommandAck:
        """MAV_CMD_NAV_TAKEOFF to ``altitude`` m above home (PX4's MIS_TAKEOFF_ALT if None).
        PX4 wants param7 as AMSL, so home's AMSL comes from GLOBAL_POSITION_INT."""
        core = self._core
        amsl = math.nan
        if altitude is not None:
            gp = core.latest(GlobalPosition) or core.wait_sample(GlobalPosition, 2.0)
            if gp is None:
                raise CommandFailed(mavlink2.MAV_CMD_NAV_TAKEOFF, None,
                                    "takeoff altitude needs GLOBAL_POSITION_INT to know home AMSL")
            amsl = gp.alt_m - gp.relative_alt_m + altitude
        return core.send_command(mavlink2.MAV_CMD_NAV_TAKEOFF, -1, 0, 0, math.nan, math.nan,
                                 math.nan, amsl)

    def goto_location(self, lat_deg: float, lon_deg: float, amsl_m: float, yaw_rad: float = math.nan) -> CommandAck:
        """MAV_CMD_DO_REPOSITION, as MAVSDK's ``goto_location``: PX4 switches to Hold and flies there at
        MPC_XY_CRUISE, only when armed, not at all outside its geofence (it ACKs first either way).
        param2 = MAV_DO_REPOSITION_FLAGS_CHANGE_MODE: PX4 refuses any other value as UNSUPPORTED. Sent as
        COMMAND_LONG, whose float32 lat/lon put the point within ~0.2 m (over PX4's Zenoh module, float64)."""
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and math.isfinite(amsl_m)
                and -90 <= lat_deg <= 90 and -180 <= lon_deg <= 180):
            raise ValueError(f"goto_location: lat {lat_deg}, lon {lon_deg}, AMSL {amsl_m} is not a position")
        return self._core.send_command(mavlink2.MAV_CMD_DO_REPOSITION, -1, 1, 0, yaw_rad, lat_deg, lon_deg, amsl_m)

    def hold_here(self) -> CommandAck:
        """DO_REPOSITION with no point: PX4 stops where it is and holds (navigator_main.cpp: all NaN pauses
        the vehicle). Unlike a switch to Hold, this also ends a reposition already under way in Hold."""
        return self._core.send_command(mavlink2.MAV_CMD_DO_REPOSITION, -1, 1, 0, math.nan, math.nan, math.nan,
                                       math.nan)

    def land(self) -> CommandAck:
        return self._core.send_command(mavlink2.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan,
                                       math.nan, math.nan)

    def return_to_launch(self) -> CommandAck:
        return self._core.send_command(mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    rtl = return_to_launch

    def hold(self) -> CommandAck:
        return self.set_mode("AUTO.LOITER")
