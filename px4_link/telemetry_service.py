"""``link.telemetry``: vehicle state, latest samples, listeners, stream rates.

The samples and listeners live in the core's telemetry cache (other plugins read it too);
this plugin measures delivered rates and keeps the requested message intervals, asking for
them again after PX4 reconnects or reboots. ``TelemetryView`` is the part PX4 over Zenoh's
telemetry plugin shares (the cache, the listeners, the measured rates)."""
from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

from .commands import CommandAck
from .plugin import Core, Listener
from .rates import RateMeter, RequestedIntervals
from .telemetry import Px4State
from .wire import mavlink2, message_id

T = TypeVar("T")
CoreT = TypeVar("CoreT", bound=Core)


class TelemetryView(Generic[CoreT]):
    """The telemetry plugin's reads of the core's cache and its rate meter; the subclass records
    into ``rates`` and keeps ``intervals``."""

    def __init__(self, core: CoreT) -> None:
        self._core = core
        self.rates = RateMeter()
        self.intervals = RequestedIntervals()

    @property
    def state(self) -> Px4State:
        return self._core.state

    def latest(self, kind: type[T]) -> T | None:
        """Most recent sample of that type (e.g. ``link.telemetry.latest(Imu)``)."""
        return self._core.latest(kind)

    def wait(self, kind: type[T], timeout: float = 5.0,
             predicate: Callable[[T], bool] | None = None) -> T | None:
        """Wait for a sample of ``kind`` newer than now (matching ``predicate``)."""
        return self._core.wait_sample(kind, timeout, predicate)

    def add_listener(self, callback: Listener, kind: type | None = None) -> Listener:
        """``callback(sample)`` for each sample (of ``kind`` only); runs on the receive thread."""
        return self._core.add_sample_listener(callback, kind)

    def remove_listener(self, callback: Listener) -> None:
        self._core.remove_sample_listener(callback)

    def rate_hz(self, message: str, window: float = 2.0) -> float:
        """Delivered rate of a message from the vehicle (over Zenoh: a MAVLink stream name, i.e. its uORB
        topic, or a ``/fmu/out`` topic), measured over ``window`` s."""
        return self.rates.rate_hz(message, window)


class Telemetry(TelemetryView[Core]):
    def __init__(self, core: Core) -> None:
        super().__init__(core)
        core.add_message_handler(None, lambda m: self.rates.record(m.get_type()))
        core.add_event_listener(self._on_event)

    def request_message_interval(self, message: str | int, hz: float) -> CommandAck:
        """MAV_CMD_SET_MESSAGE_INTERVAL (hz <= 0 disables); remembered and asked again
        after PX4 reconnects or reboots."""
        mid = message_id(message)
        self.intervals.remember(mid, hz)
        return self._send_interval(mid, hz)

    def _send_interval(self, mid: int, hz: float) -> CommandAck:
        interval_us = 1e6 / hz if hz > 0 else -1
        return self._core.send_command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mid, interval_us)

    def reapply_intervals(self) -> int:
        """Ask again for every remembered interval; returns how many were accepted."""
        ok = 0
        for mid, hz in self.intervals.items():
            try:
                self._send_interval(mid, hz)
                ok += 1
            except Exception as e:  # noqa: BLE001 - reported, retried on the next reconnect
                self._core.rlog.warning("reinterval", "px4_link: re-requesting message %d at "
                                        "%g Hz failed: %s", mid, hz, e)
        return ok

    def _on_event(self, name: str, details: dict[str, Any]) -> None:
        # PX4 forgets requested intervals when it reboots (and we cannot tell a reconnect from one).
        if name == "rebooted" or (name == "connected" and details.get("reconnect")):
            self._reapply_intervals_later()

    def _reapply_intervals_later(self) -> None:
        # Commands wait for ACKs that the receive thread (ours, now) delivers: run them elsewhere.
        if not self.intervals.items():
            return

        def run() -> None:
            core = self._core
            core.wait_until(lambda: core.connected, 5.0)
            core.count("interval_rerequests", self.reapply_intervals())

        threading.Thread(target=run, name="px4link-intervals", daemon=True).start()
