"""``link.offboard``: the validated setpoint stream and OFFBOARD entry/exit.

The plugin owns its stream: a periodic hook on the core's send thread repeats the latest
setpoint at the link's tick rate (``setpoint_rate_hz``), and a mode hook on the receive
thread tells a loss of OFFBOARD from our own switch away."""
from __future__ import annotations

import threading
import time

from .action import set_mode
from .commands import CommandAck
from .plugin import Core, Event
from .targets import Geofence, Target, TargetRefused, TargetValidator, mavlink_fields
from .telemetry import LocalPosition


class Offboard:
    """Setpoints are checked (finite, geofence, speed/jump) before anything is sent; the
    core's send thread repeats the latest one at ``setpoint_rate_hz`` through ``_tick``."""

    def __init__(self, core: Core, geofence: Geofence | None, max_speed: float | None) -> None:
        self._core = core
        self._validator = TargetValidator(geofence, max_speed)
        self._lock = threading.Lock()
        self.setpoint: Target | None = None
        self._streaming = False
        self._stream_started: float | None = None
        self._active = False
        self.leaving = False   # set while we switch away ourselves: not an "offboard_lost"
        self._t0 = time.monotonic()   # time_boot_ms of our setpoints counts from here
        core.add_periodic(self._tick)
        core.add_mode_hook(self._on_mode_change)

    @property
    def streaming(self) -> bool:
        return self._streaming

    @property
    def is_active(self) -> bool:
        """True between a successful start() and stop() or PX4 leaving OFFBOARD."""
        return self._active

    def set_setpoint(self, sp: Target) -> None:
        """Validate and stream ``sp``; the first one starts the stream. Raises
        TargetRefused (nothing is sent)."""
        core = self._core
        now = time.monotonic()
        lp = core.latest(LocalPosition)
        vehicle_pos = lp.position if lp is not None and now - lp.received_at < 1.0 else None
        try:
            self._validator.check(sp, now, vehicle_pos)
        except TargetRefused as e:
            core.count("setpoints_rejected")
            core.emit("setpoint_rejected", {"setpoint": sp, "reason": e.reason, "message": str(e)})
            raise
        self._validator.accept(sp, now)
        with self._lock:
            self.setpoint = sp
            if not self._streaming:
                self._streaming = True
                self._stream_started = now
        self._send(sp)   # at once rather than at the next tick: setpoint age matters

    def stop_stream(self) -> None:
        """Stop streaming (the setpoint is kept). In OFFBOARD this makes PX4 fail safe
        after COM_OF_LOSS_T, which the link reports as ``offboard_lost``."""
        with self._lock:
            self._streaming = False
            self._stream_started = None

    def start(self, prestream_s: float = 1.2, confirm_timeout: float = 3.0) -> CommandAck:
        """Stream for ``prestream_s`` (PX4 wants ~1 s at > 2 Hz first), then OFFBOARD."""
        with self._lock:
            if self.setpoint is None:
                raise TargetRefused("no_setpoint", "offboard.start needs a setpoint first "
                                                   "(call set_setpoint)")
            if not self._streaming:
                self._streaming = True
                self._stream_started = time.monotonic()
            started = self._stream_started or time.monotonic()
        wait = prestream_s - (time.monotonic() - started)
        if wait > 0:
            time.sleep(wait)
        ack = set_mode(self._core, "OFFBOARD", confirm_timeout)
        self._active = True
        return ack

    def stop(self, mode: str | None = "AUTO.LOITER") -> CommandAck | None:
        """Leave OFFBOARD cleanly: switch to ``mode`` while still streaming (PX4 never sees
        a loss), then stop the stream. ``mode=None`` only stops the stream."""
        ack = None
        self.leaving = True
        try:
            if mode is not None and self._core.connected:
                ack = set_mode(self._core, mode)
        finally:
            self._active = False
            self.leaving = False
            self.stop_stream()
        return ack

    def _on_mode_change(self, old: str, new: str) -> list[Event]:
        """Mode hook (receive thread): PX4 leaving OFFBOARD while we did not ask is a loss."""
        if old != "OFFBOARD":
            return []
        lost = self._active and not self.leaving
        if not lost:
            return []
        self._active = False
        return [("offboard_lost", {"new_mode": new})]

    def _tick(self) -> None:
        """Periodic hook (send thread): repeat the latest setpoint while streaming."""
        sp = self.setpoint
        if self._streaming and sp is not None:
            self._send(sp)

    def _send(self, sp: Target) -> None:
        core = self._core
        if not core.can_send:
            return
        sysid, compid = core.vehicle_ids()
        boot_ms = int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF
        core.send_message(core.encoder().set_position_target_local_ned_encode(
            boot_ms, sysid, compid, **mavlink_fields(sp)))
        core.count("setpoints_sent")
