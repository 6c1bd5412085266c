"""``link.telemetry``: vehicle state, latest samples, listeners, stream rates."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

from .commands import CommandAck
from .rates import RateMeter, RequestedIntervals
from .telemetry import Px4State
from .wire import mavlink2, message_id

if TYPE_CHECKING:
    from .link import Px4Link

T = TypeVar("T")
Listener = Callable[[Any], None]


class Telemetry:
    def __init__(self, link: "Px4Link") -> None:
        self._link = link
        self._latest: dict[type, Any] = {}
        self._listeners: list[tuple[type | None, Listener]] = []
        self._lock = threading.Lock()
        self.rates = RateMeter()
        self.intervals = RequestedIntervals()

    @property
    def state(self) -> Px4State:
        return self._link.state

    def latest(self, kind: type[T]) -> T | None:
        """Most recent sample of that type (e.g. ``link.telemetry.latest(Imu)``)."""
        return self._latest.get(kind)

    def wait(self, kind: type[T], timeout: float = 5.0,
             predicate: Callable[[T], bool] | None = None) -> T | None:
        """Wait for a sample of ``kind`` newer than now (matching ``predicate``)."""
        since = time.monotonic()

        def fresh() -> bool:
            v = self._latest.get(kind)
            return v is not None and v.received_at >= since and (predicate is None or predicate(v))

        return self._latest.get(kind) if self._link.wait_until(fresh, timeout) else None

    def add_listener(self, callback: Listener, kind: type | None = None) -> Listener:
        """``callback(sample)`` for each sample (of ``kind`` only); runs on the receive thread."""
        with self._lock:
            self._listeners.append((kind, callback))
        return callback

    def remove_listener(self, callback: Listener) -> None:
        with self._lock:
            self._listeners = [(k, c) for k, c in self._listeners if c is not callback]

    def publish(self, sample: Any) -> None:
        """Receive thread: store the (already validated) sample and call listeners."""
        self._latest[type(sample)] = sample
        self._link.notify()
        for kind, cb in list(self._listeners):
            if kind is None or isinstance(sample, kind):
                self._link.safe_call(cb, sample)

    def rate_hz(self, message: str, window: float = 2.0) -> float:
        """Delivered rate of a MAVLink message from the vehicle, measured over ``window`` s."""
        return self.rates.rate_hz(message, window)

    def request_message_interval(self, message: str | int, hz: float) -> CommandAck:
        """MAV_CMD_SET_MESSAGE_INTERVAL (hz <= 0 disables); remembered and asked again
        after PX4 reconnects or reboots."""
        mid = message_id(message)
        self.intervals.remember(mid, hz)
        return self._send_interval(mid, hz)

    def _send_interval(self, mid: int, hz: float) -> CommandAck:
        interval_us = 1e6 / hz if hz > 0 else -1
        return self._link.send_command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mid, interval_us)

    def reapply_intervals(self) -> int:
        """Ask again for every remembered interval; returns how many were accepted."""
        ok = 0
        for mid, hz in self.intervals.items():
            try:
                self._send_interval(mid, hz)
                ok += 1
            except Exception as e:  # noqa: BLE001 - reported, retried on the next reconnect
                self._link.rlog.warning("reinterval", "px4_link: re-requesting message %d at "
                                        "%g Hz failed: %s", mid, hz, e)
        return ok
