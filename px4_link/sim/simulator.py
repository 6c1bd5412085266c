"""Simulator: one PX4-like vehicle on a UDP port, run by a single loop thread.

The loop sleeps in select() until the next physics step or telemetry message is due, so
it costs little CPU. The vehicle, its rules and the introspection properties tests read from any
thread (mode, armed, position, setpoints_received, mode_log, ...) are ``SimulatorBase``'s (base.py),
shared with PX4's-Zenoh simulator; this module is the MAVLink front end; everything else goes over MAVLink.
"""
from __future__ import annotations

import logging
import select
import socket
import time
import traceback
from collections.abc import Sequence
from typing import ClassVar

from .available_modes import AvailableModes
from .base import DEFAULT_HOME, SimulatorBase
from .commander import PX4_ESTIMATOR_WARMUP_S
from .faults import Fault
from .protocol import SimProtocol, StreamTable

log = logging.getLogger(__name__)


class Simulator(SimulatorBase):
    """A PX4-faithful MAVLink vehicle.

    ``port`` is our UDP source port (PX4 SITL: 14580; 0 = ephemeral, see ``.port`` after
    start), ``target_port`` where we send (PX4 SITL: 14540).
    """

    _log: ClassVar[logging.Logger] = log

    def __init__(self, sysid: int = 1, *, compid: int = 1, port: int = 14580,
                 target_port: int = 14540, target_host: str = "127.0.0.1",
                 bind_host: str = "127.0.0.1", params: dict[str, float | int] | None = None,
                 rates: dict[str, float] | None = None,
                 home: tuple[float, float, float] = DEFAULT_HOME, physics_hz: float = 100.0,
                 seed: int | None = None, estimator_warmup_s: float = PX4_ESTIMATOR_WARMUP_S,
                 faults: Sequence[Fault] = ()) -> None:
        super().__init__(sysid, params=params, home=home, physics_hz=physics_hz, seed=seed,
                         estimator_warmup_s=estimator_warmup_s, faults=faults)
        self.compid = compid
        self._bind = (bind_host, port)
        self.target = (target_host, target_port)
        self.streams = StreamTable(rates)
        # What AVAILABLE_MODES lists. No external mode registers over MAVLink (PX4 takes registrations over
        # uORB/DDS/Zenoh): ``register_external_mode`` is where one would enter.
        self.available_modes = AvailableModes()
        self._sock: socket.socket | None = None
        self.protocol: SimProtocol | None = None
        self.loop_iterations = 0

    # ---------------------------------------------------------------- lifecycle
    def _before_start(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(self._bind)
        sock.setblocking(False)
        self._sock = sock
        self.protocol = SimProtocol(sock, self.target, self.sysid, self.compid, self.commander,
                                    self.vehicle, self.params, self.streams, self.home,
                                    self._boot, on_log=lambda s: log.debug("sim%d: %s", self.sysid, s),
                                    on_internal_error=self._internal_error, modes=self.available_modes)
        self.protocol.on_heartbeat = self.failsafes.on_heartbeat

    def _after_stop(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    # ---------------------------------------------------------------- loop
    def _run(self) -> None:
        proto = self.protocol
        assert proto is not None and self._sock is not None
        next_phys = time.monotonic()
        next_hb = next_phys
        readable = True
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                try:
                    if readable:   # most wake-ups are timers: a recvfrom raising EAGAIN costs as much as a step
                        proto.drain(now)
                    next_phys = self._advance(now, next_phys)
                    proto.flush_statustexts()
                    if now >= next_hb:
                        proto.heartbeat()
                        next_hb = now + 1.0
                    proto.send_commands()
                    proto.send_streams(now)
                except Exception:
                    self._internal_error(f"loop: {traceback.format_exc()}")
                self.loop_iterations += 1
            wake = min(next_phys, next_hb, self.streams.next_due() or next_phys)
            timeout = max(0.0, wake - time.monotonic())
            try:
                readable = bool(select.select([self._sock], [], [], timeout)[0])
            except (OSError, ValueError):
                break

    # ---------------------------------------------------------------- the front end's records
    def _setpoint_record(self) -> list[tuple[float, tuple[float, float, float] | None]]:
        """Each SET_POSITION_TARGET_LOCAL_NED received."""
        return list(self.protocol.setpoint_log) if self.protocol is not None else []

    def _command_record(self) -> list[tuple[float, int, int]]:
        """COMMAND_LONG/INT answered: (time, MAV_CMD, MAV_RESULT)."""
        return list(self.protocol.stats.commands) if self.protocol else []

    def register_external_mode(self, name: str) -> int:
        """List an external mode as if a component had registered ``name`` (its nav_state): AVAILABLE_MODES
        names it and AVAILABLE_MODES_MONITOR announces the change, as PX4's do. The simulator cannot fly it."""
        with self._lock:
            return self.available_modes.register(name)

    def unregister_external_mode(self, nav_state: int) -> None:
        with self._lock:
            self.available_modes.unregister(nav_state)

    # ---------------------------------------------------------------- introspection (MAVLink's own)
    @property
    def gcs_connection_lost(self) -> bool:
        """PX4's vehicle_status.gcs_connection_lost: no MAV_TYPE_GCS heartbeat (true from boot)."""
        return self.failsafes.gcs_connection_lost

    @property
    def port(self) -> int:
        """The UDP port we send from / listen on."""
        if self._sock is None:
            return self._bind[1]
        port: int = self._sock.getsockname()[1]
        return port

    @property
    def system_status(self) -> int:
        """HEARTBEAT system_status: 5 (CRITICAL) while a failsafe is active."""
        c = self.commander
        return 8 if c.mode == "TERMINATION" else 5 if c.failsafe else 4 if c.armed else 3

    @property
    def message_rates(self) -> dict[str, float]:
        """Rates requested (or default), Hz."""
        return dict(self.streams.rates)

    @property
    def not_simulated_intervals(self) -> dict[str, float]:
        """Intervals asked (us: -1 off, 0 default) for PX4 streams the simulator does not send."""
        return dict(self.streams.not_simulated_us)

    @property
    def delivered_rates(self) -> dict[str, float]:
        """Rates actually sent, Hz (sensor-sample quantised, as PX4 does)."""
        return {n: self.streams.delivered_hz(n) for n in self.streams.rates}

    @property
    def messages_sent(self) -> dict[str, int]:
        with self._lock:
            return dict(self.protocol.stats.sent_by_type) if self.protocol else {}

    @property
    def bad_frames_received(self) -> int:
        return self.protocol.stats.bad_frames if self.protocol else 0
