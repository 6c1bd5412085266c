"""The flat Px4Link API of the previous release, kept one release as deprecated aliases
of ``link.action`` / ``link.offboard`` / ``link.param`` / ``link.telemetry``."""
from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .action import Action
    from .offboard import Offboard
    from .param import Param
    from .telemetry_service import Telemetry


def _alias(plugin: str, method: str) -> Callable[..., Any]:
    def call(self: Any, *args: Any, **kwargs: Any) -> Any:
        warnings.warn(f"this flat Px4Link method is deprecated; use link.{plugin}.{method}",
                      DeprecationWarning, stacklevel=2)
        return getattr(getattr(self, plugin), method)(*args, **kwargs)
    call.__doc__ = f"Deprecated: ``link.{plugin}.{method}``."
    return call


class LegacyApi:
    action: "Action"
    offboard: "Offboard"
    param: "Param"
    telemetry: "Telemetry"

    arm = _alias("action", "arm")
    disarm = _alias("action", "disarm")
    takeoff = _alias("action", "takeoff")
    land = _alias("action", "land")
    rtl = _alias("action", "return_to_launch")
    hold = _alias("action", "hold")
    set_mode = _alias("action", "set_mode")
    get_param = _alias("param", "get")
    set_param = _alias("param", "set")
    set_setpoint = _alias("offboard", "set_setpoint")
    stop_setpoint_stream = _alias("offboard", "stop_stream")
    start_offboard = _alias("offboard", "start")
    stop_offboard = _alias("offboard", "stop")
    latest = _alias("telemetry", "latest")
    wait_telemetry = _alias("telemetry", "wait")
    add_listener = _alias("telemetry", "add_listener")
    remove_listener = _alias("telemetry", "remove_listener")
    request_message_interval = _alias("telemetry", "request_message_interval")

    @property
    def setpoint(self) -> Any:
        """Deprecated: ``link.offboard.setpoint``."""
        return self.offboard.setpoint

    @property
    def streaming(self) -> bool:
        """Deprecated: ``link.offboard.streaming``."""
        return self.offboard.streaming

    @property
    def offboard_active(self) -> bool:
        """Deprecated: ``link.offboard.is_active``."""
        return self.offboard.is_active
