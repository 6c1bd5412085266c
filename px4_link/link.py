"""Px4Link: the link to PX4 as users see it, a plugin manager in MAVSDK's way.

``LinkCore`` (core.py) owns the connection, threads and dispatch; the plugins
``link.action``, ``link.offboard``, ``link.param`` and ``link.telemetry`` sit on it through
the narrow ``plugin.Core`` interface and register their own hooks (the offboard stream is
a periodic hook of the core's send thread). ``Px4Link`` builds both and forwards the few
link-wide calls (those both backends share are ``vehicle.VehicleLinkBase``'s); see core.py and
vehicle_core.py for the threading contract.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from .action import Action
from .commands import CommandError
from .core import LinkCore
from .mode_list import AvailableMode, ModeList
from .offboard import VELOCITY_TIMEOUT_S, Offboard
from .param import Param
from .plugin import EventCallback
from .stats import LinkStats
from .targets import Geofence
from .telemetry_service import Telemetry
from .transport import Address
from .vehicle import VehicleLinkBase
from .wire import load_signing_key

DEFAULT_CONNECTION = "udpin:127.0.0.1:14540"

_DEFAULT_GEOFENCE = Geofence()


class Px4Link(VehicleLinkBase[LinkCore]):
    """MAVLink adapter to PX4. Use as a context manager::

        with Px4Link("udpin:127.0.0.1:14540") as link:
            link.wait_connected(10)
            link.action.arm(); link.action.takeoff(5)

    The default listens on loopback only (PX4 SITL / a local autopilot bridge). For a
    companion talking to a flight controller over the network use e.g.
    ``udpin:0.0.0.0:14540`` and consider ``signing_key_file``; on a serial port or USB,
    ``/dev/ttyAMA0:921600`` or ``serial:///dev/ttyACM0`` (every form: ``connection_url``).

    Events delivered to ``on_event(name, details)``: connected, disconnected, rebooted,
    mode_changed, armed_changed, landed_changed, offboard_lost, setpoint_rejected, setpoint_clamped,
    setpoint_expired (offboard.py), statustext, modes_listed (``count``: PX4's mode list read, mode_list.py);
    on a serial port also link_down (the device vanished:
    ``why``), link_up (bytes through it again) and baud_mismatch (``why``: bytes but no frame).
    Callbacks run on the link's threads: keep them short (see core.py).
    """

    def __init__(self, connection: str = DEFAULT_CONNECTION, *,
                 heartbeat_timeout: float = 3.0,
                 setpoint_rate_hz: float = 20.0,
                 geofence: Geofence | None = _DEFAULT_GEOFENCE,
                 max_speed: float | None = 10.0,
                 velocity_timeout_s: float = VELOCITY_TIMEOUT_S,
                 source_system: int = 245,
                 source_component: int = 191,  # MAV_COMP_ID_ONBOARD_COMPUTER
                 target_system: int | None = None,
                 on_event: EventCallback | None = None,
                 command_timeout: float = 1.0,
                 command_retries: int = 3,
                 signing_key: bytes | None = None,
                 signing_key_file: str | None = None,
                 baud: int = 921600) -> None:
        if setpoint_rate_hz < 10.0:
            # PX4 needs > 2 Hz; 10 Hz keeps a margin for a lossy serial/UDP hop.
            raise ValueError("setpoint_rate_hz must be >= 10")
        key = signing_key if signing_key is not None else \
            (load_signing_key(signing_key_file) if signing_key_file else None)
        # The core's send thread ticks at the setpoint rate: the offboard stream is its hook.
        self._core = LinkCore(connection, heartbeat_timeout=heartbeat_timeout, tick_hz=setpoint_rate_hz,
                              source_system=source_system, source_component=source_component,
                              target_system=target_system, command_timeout=command_timeout,
                              command_retries=command_retries, signing_key=key, baud=baud)
        if on_event is not None:   # first, as before: the user's callback sees each event first
            self._core.add_event_listener(on_event)
        self._version: Any = None            # the last AUTOPILOT_VERSION (firmware_version asks for it)
        self._version_seen = threading.Event()
        self._core.add_message_handler("AUTOPILOT_VERSION", self._on_version)
        self.action = Action(self._core)
        self.offboard = Offboard(self._core, geofence, max_speed, velocity_timeout_s)
        self.param = Param(self._core)
        self.telemetry = Telemetry(self._core)
        self.modes = ModeList(self._core)

    @property
    def connection(self) -> str:
        return self._core.connection

    @property
    def local_port(self) -> int | None:
        """Port we are bound to (useful with ``udpin:127.0.0.1:0``)."""
        return self._core.local_port

    @property
    def vehicle_address(self) -> Address | None:
        """The address the link is locked onto (None before the first autopilot heartbeat)."""
        return self._core.vehicle_address

    # ----------------------------------------------------------------- raw frames
    def add_frame_listener(self, listener: Callable[[bytes], None]) -> None:
        """``listener(frame)`` with the bytes of every frame accepted from the vehicle, as received, on the
        receive thread (quick, never raising); may be added while the link runs. With ``send_raw`` this is
        what a MAVLink router needs of the link (the companion's tunnel to a QGC on a serial PX4)."""
        self._core.add_frame_listener(listener)

    def send_raw(self, frame: bytes) -> bool:
        """Write one whole MAVLink frame built elsewhere to the vehicle, between the link's own frames;
        thread-safe, never blocks. False (nothing written, nothing queued) when it cannot go now: no wire,
        or a serial line busy with the link's own traffic, which always comes first."""
        return self._core.send_raw(frame)

    # ----------------------------------------------------------------- state
    @property
    def stats(self) -> LinkStats:
        return self._core.stats

    def not_connected_reason(self) -> str:
        """Why no vehicle is connected: the wire's state first (a port gone, a wrong baud rate)."""
        return self._core.not_connected_reason()

    def firmware_version(self, timeout: float = 3.0) -> str | None:
        """PX4's firmware as it names itself (AUTOPILOT_VERSION, asked with MAV_CMD_REQUEST_MESSAGE), e.g.
        ``v1.15.0 (official), git 1a2b3c4d``; None when the vehicle does not answer within ``timeout``."""
        self._version_seen.clear()
        try:
            self.send_command(MAV_CMD_REQUEST_MESSAGE, AUTOPILOT_VERSION_ID, timeout=timeout / 2, retries=1)
        except CommandError:
            return None
        if not self._version_seen.wait(timeout) or self._version is None:
            return None
        m = self._version
        return describe_version(int(m.flight_sw_version), bytes(m.flight_custom_version))

    def available_modes(self, wait: float = 0.0) -> list[AvailableMode]:
        """The modes PX4 offers (AVAILABLE_MODES, asked by the link on connect and again when PX4 announces a
        change): (index, standard_mode, custom_mode, name, flags) each, external modes by their registered
        names; [] before the list is complete, or from a PX4 without it (before v1.15). ``wait`` > 0: wait that
        long at most for the list. ``link.modes.current`` is the last CURRENT_MODE."""
        return self.modes.available(wait)

    def _on_version(self, m: Any) -> None:     # the receive thread
        self._version = m
        self._version_seen.set()

    def backend_summary(self) -> dict[str, Any]:
        """For the companion's summary (``vehicle.VehicleLink``)."""
        return {"backend": "mavlink", "connection": self.connection}


MAV_CMD_REQUEST_MESSAGE = 512
AUTOPILOT_VERSION_ID = 148
# FIRMWARE_VERSION_TYPE, the low byte of flight_sw_version
_VERSION_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}


def describe_version(sw_version: int, custom: bytes) -> str:
    """AUTOPILOT_VERSION's flight_sw_version (major, minor, patch, type bytes) and flight_custom_version
    (PX4: the first 8 bytes of its git hash) as text."""
    major, minor, patch, kind = (sw_version >> 24) & 0xFF, (sw_version >> 16) & 0xFF, (sw_version >> 8) & 0xFF, \
        sw_version & 0xFF
    text = f"v{major}.{minor}.{patch} ({_VERSION_TYPES.get(kind, f'type {kind}')})"
    if any(custom):   # PX4 copies its git hash's first 16 hex digits as a little-endian uint64
        text += f", git {custom[:8][::-1].hex()}"
    return text

