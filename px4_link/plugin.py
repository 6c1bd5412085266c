"""What a plugin (``action``, ``offboard``, ``param``, ``telemetry``) may use of the link.

Plugins type against ``Core`` and never against ``Px4Link`` or ``LinkCore``, so the way of
a call stays one-way: plugin -> core -> transport. A plugin that needs to react to the
vehicle registers a hook with the core instead of the core knowing about the plugin.

Threading: message handlers and mode hooks run on the receive thread, periodic hooks on
the send thread (at the link's tick rate, with the heartbeat); all must be short and must
never wait for the vehicle (an ACK is delivered by the receive thread).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from .commands import CommandAck
from .ratelimit import RateLimitedLog
from .telemetry import Px4State
from .wire import Encoder

T = TypeVar("T")

Event = tuple[str, dict[str, Any]]
EventCallback = Callable[[str, dict[str, Any]], None]
Listener = Callable[[Any], None]
MessageHandler = Callable[[Any], None]
# (old mode, new mode) -> events to emit after mode_changed, in the same batch
ModeHook = Callable[[str, str], list[Event]]
PeriodicHook = Callable[[], None]


class Core(Protocol):
    rlog: RateLimitedLog

    # --- the vehicle and its ids
    @property
    def connected(self) -> bool: ...
    @property
    def state(self) -> Px4State: ...
    @property
    def can_send(self) -> bool:
        """Started and a vehicle is connected."""
    def vehicle_ids(self) -> tuple[int, int]: ...

    # --- sending
    def encoder(self) -> Encoder: ...
    def send_message(self, msg: Any) -> None: ...
    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck: ...

    # --- waiting, counters, events
    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool: ...
    def notify(self) -> None: ...
    def count(self, key: str, n: int = 1) -> None: ...
    def emit(self, name: str, details: dict[str, Any]) -> None: ...
    def add_event_listener(self, callback: EventCallback) -> None: ...

    # --- the telemetry cache
    def latest(self, kind: type[T]) -> T | None: ...
    def wait_sample(self, kind: type[T], timeout: float,
                    predicate: Callable[[T], bool] | None = None) -> T | None: ...
    def add_sample_listener(self, callback: Listener, kind: type | None = None) -> Listener: ...
    def remove_sample_listener(self, callback: Listener) -> None: ...

    # --- hooks
    def add_message_handler(self, mtype: str | None, handler: MessageHandler) -> None:
        """``handler(msg)`` for each accepted message of ``mtype`` (None: every message)."""
    def add_mode_hook(self, hook: ModeHook) -> None: ...
    def add_periodic(self, hook: PeriodicHook) -> None: ...
