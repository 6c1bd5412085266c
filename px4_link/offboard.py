"""``link.offboard``: the validated setpoint stream and OFFBOARD entry/exit."""
from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from .commands import CommandAck
from .setpoints import Geofence, OffboardSetpoint, SetpointRejected, SetpointValidator
from .telemetry import LocalPosition

if TYPE_CHECKING:
    from .link import Px4Link

OffboardError = SetpointRejected


class Offboard:
    """Setpoints are checked (finite, geofence, speed/jump) before anything is sent; the
    link's stream thread repeats the latest one at ``setpoint_rate_hz``."""

    def __init__(self, link: "Px4Link", geofence: Geofence | None, max_speed: float | None) -> None:
        self._link = link
        self._validator = SetpointValidator(geofence, max_speed)
        self._lock = threading.Lock()
        self.setpoint: OffboardSetpoint | None = None
        self._streaming = False
        self._stream_started: float | None = None
        self._active = False
        self.leaving = False   # set while we switch away ourselves: not an "offboard_lost"

    @property
    def streaming(self) -> bool:
        return self._streaming

    @property
    def is_active(self) -> bool:
        """True between a successful start() and stop() or PX4 leaving OFFBOARD."""
        return self._active

    def set_setpoint(self, sp: OffboardSetpoint) -> None:
        """Validate and stream ``sp``; the first one starts the stream. Raises
        SetpointRejected (nothing is sent)."""
        link = self._link
        now = time.monotonic()
        lp = link.telemetry.latest(LocalPosition)
        vehicle_pos = lp.position if lp is not None and now - lp.received_at < 1.0 else None
        try:
            self._validator.check(sp, now, vehicle_pos)
        except SetpointRejected as e:
            link.count("setpoints_rejected")
            link.emit("setpoint_rejected", {"setpoint": sp, "reason": e.reason, "message": str(e)})
            raise
        self._validator.accept(sp, now)
        with self._lock:
            self.setpoint = sp
            if not self._streaming:
                self._streaming = True
                self._stream_started = now
        link.send_setpoint(sp)   # at once rather than at the next tick: setpoint age matters

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
                raise SetpointRejected("no_setpoint", "offboard.start needs a setpoint first "
                                                      "(call set_setpoint)")
            if not self._streaming:
                self._streaming = True
                self._stream_started = time.monotonic()
            started = self._stream_started or time.monotonic()
        wait = prestream_s - (time.monotonic() - started)
        if wait > 0:
            time.sleep(wait)
        ack = self._link.action.set_mode("OFFBOARD", confirm_timeout)
        self._active = True
        return ack

    def stop(self, mode: str | None = "AUTO.LOITER") -> CommandAck | None:
        """Leave OFFBOARD cleanly: switch to ``mode`` while still streaming (PX4 never sees
        a loss), then stop the stream. ``mode=None`` only stops the stream."""
        ack = None
        self.leaving = True
        try:
            if mode is not None and self._link.connected:
                ack = self._link.action.set_mode(mode)
        finally:
            self._active = False
            self.leaving = False
            self.stop_stream()
        return ack

    def on_mode_left(self) -> bool:
        """PX4 left OFFBOARD (receive thread); True when that is a loss, not our doing."""
        lost = self._active and not self.leaving
        if lost:
            self._active = False
        return lost
