"""``VehicleLink``: what the companion uses of a link to PX4, whatever carries it.

``Px4Link`` (MAVLink) and ``px4_zenoh.Px4ZenohLink`` (PX4's own Zenoh module) both satisfy it, so
the companion types against this and never against one backend. Both hang the same ``Action`` and
an ``Offboard`` on a ``plugin.Core``; parameters and telemetry differ by backend, hence the two small
protocols below. ``VehicleLinkBase`` is what both facades forward to their core alike.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, Protocol, Self, TypeVar

from .action import Action
from .commands import CommandAck
from .offboard import Offboard
from .plugin import EventCallback, Listener
from .rates import RequestedIntervals
from .telemetry import Px4State
from .vehicle_core import VehicleCore

T = TypeVar("T")
CoreT = TypeVar("CoreT", bound=VehicleCore)


class VehicleParams(Protocol):
    def set(self, name: str, value: float | int, timeout: float = ..., retries: int = ...) -> float | int: ...
    def get(self, name: str, timeout: float = ..., retries: int = ...) -> float | int: ...


class VehicleTelemetry(Protocol):
    @property
    def intervals(self) -> RequestedIntervals: ...
    def latest(self, kind: type[T]) -> T | None: ...
    def add_listener(self, callback: Listener, kind: type | None = None) -> Listener: ...
    def remove_listener(self, callback: Listener) -> None: ...
    def rate_hz(self, message: str, window: float = 2.0) -> float: ...
    def request_message_interval(self, message: str | int, hz: float) -> CommandAck: ...


class VehicleLink(Protocol):
    @property
    def action(self) -> Action: ...
    @property
    def offboard(self) -> Offboard: ...
    @property
    def param(self) -> VehicleParams: ...
    @property
    def telemetry(self) -> VehicleTelemetry: ...
    @property
    def connected(self) -> bool: ...
    @property
    def state(self) -> Px4State: ...
    @property
    def mode(self) -> str: ...
    @property
    def armed(self) -> bool: ...
    @property
    def system_id(self) -> int | None: ...
    def backend_summary(self) -> dict[str, Any]:
        """What the companion's summary shows of the backend (its kind, its connection, its own figures)."""
    def wait_connected(self, timeout: float = 10.0) -> bool: ...
    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool: ...
    def add_event_listener(self, callback: EventCallback) -> None: ...
    def cancel_command(self, owner: int, why: str) -> bool: ...
    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck: ...


class VehicleLinkBase(Generic[CoreT]):
    """The part of ``VehicleLink`` that only forwards to the core (``Px4Link``, ``Px4ZenohLink``).

    Use as a context manager. Callbacks run on the core's threads: keep them short (vehicle_core.py)."""

    _core: CoreT

    # ----------------------------------------------------------------- lifecycle
    def start(self) -> Self:
        self._core.start()
        return self

    def stop(self) -> None:
        """Stop both threads and close what the core opened; safe to call twice."""
        self._core.stop()

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ----------------------------------------------------------------- state
    @property
    def connected(self) -> bool:
        return self._core.connected

    @property
    def state(self) -> Px4State:
        return self._core.state

    @property
    def mode(self) -> str:
        return self._core.state.mode

    @property
    def armed(self) -> bool:
        return self._core.state.armed

    @property
    def system_id(self) -> int | None:
        return self._core.state.system_id

    def wait_connected(self, timeout: float = 10.0) -> bool:
        """Block until a vehicle heartbeat is seen; False on timeout."""
        return self._core.wait_until(lambda: self._core.connected, timeout)

    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Poll ``predicate`` (woken by every telemetry/heartbeat) until true or timeout."""
        return self._core.wait_until(predicate, timeout)

    def add_event_listener(self, callback: EventCallback) -> None:
        self._core.add_event_listener(callback)

    def cancel_command(self, owner: int, why: str) -> bool:
        """Withdraw the command thread ``owner`` (a ``threading.get_ident()``) is waiting on: it
        raises CommandCancelled at once and sends no more retries. True if there was one."""
        return self._core.cancel_command(owner, why)

    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck:
        """A command to the vehicle; returns the ACK or raises a CommandError subclass."""
        return self._core.send_command(command, *params, timeout=timeout, retries=retries)
