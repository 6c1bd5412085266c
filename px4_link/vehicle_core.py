"""VehicleCore: the half of a ``plugin.Core`` that does not depend on how PX4 is reached.

``core.LinkCore`` (MAVLink) and ``px4_zenoh.core.ZenohCore`` (PX4's own Zenoh module) both extend
it with their connection, their receive loop and their sending; this class holds what they share:
the vehicle state (connect, mode, armed, landed, disconnect and the events they raise), the
counters, the event bus, the telemetry cache with its listeners, the command sender's ACK filter,
and the two threads' lifecycle (a receive thread the subclass runs; a send thread that ticks at
``tick_hz``: the subclass's ``_tick`` then the periodic hooks).

Threading contract: listeners, hooks and ``on_event`` callbacks run ON the receive or send thread:
they must be short and never block (no commands from a callback: a command waits for an ACK the
receive thread would have to deliver). A callback that raises is logged (rate-limited) and
counted in ``callback_errors``. ``state`` is replaced whole under the lock, so readers never see a
torn one; every change wakes ``wait_until``.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import Any, TypeVar

from .commands import CommandAck, CommandSender, NotConnected, command_name
from .plugin import Event, EventCallback, Listener, ModeHook, PeriodicHook
from .ratelimit import RateLimitedLog
from .telemetry import Px4State

T = TypeVar("T")
# Names an external mode this process flies itself (px4_zenoh's external modes): its key (the state's
# custom_mode) -> (registered name, the PX4 mode it replaces or None), or None when it is not one of its own.
ModeNamer = Callable[[int], "tuple[str, str | None] | None"]


class VehicleCore:
    """Subclasses set ``_commands`` and implement ``_open``, ``_close``, ``_rx_loop`` and ``_tick``."""

    _commands: CommandSender

    def __init__(self, *, log: logging.Logger, tag: str, thread_prefix: str, counters: Iterable[str],
                 heartbeat_timeout: float, tick_hz: float, source_system: int, source_component: int) -> None:
        self.heartbeat_timeout = heartbeat_timeout
        self.tick_hz = tick_hz
        self.source_system = source_system
        self.source_component = source_component
        self.rlog = RateLimitedLog(log, burst=1, interval=5.0)
        self._log = log
        self._tag = tag   # the prefix of log texts ("px4_link", "px4_zenoh"): users filter on it
        self._thread_prefix = thread_prefix

        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._state = Px4State()
        self._stats: dict[str, int] = dict.fromkeys(counters, 0)
        self._ever_connected = False

        self._event_listeners: list[EventCallback] = []
        self._latest: dict[type, Any] = {}
        self._listeners: list[tuple[type | None, Listener]] = []
        self._listeners_lock = threading.Lock()
        self._mode_hooks: list[ModeHook] = []
        self._periodic: list[PeriodicHook] = []
        self._external_names: dict[int, str] = {}   # custom_mode -> registered name (PX4's list), replaced whole
        self._mode_namers: tuple[ModeNamer, ...] = ()   # replaced whole: added while running

        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    # ----------------------------------------------------------------- hooks
    def add_mode_hook(self, hook: ModeHook) -> None:
        """``hook(old, new)`` under the state lock when PX4's mode changes; the events it
        returns are emitted right after ``mode_changed``."""
        self._mode_hooks.append(hook)

    def add_periodic(self, hook: PeriodicHook) -> None:
        """``hook()`` on the send thread at every tick, after the subclass's own tick work."""
        self._periodic.append(hook)

    def set_external_mode_names(self, names: dict[int, str]) -> None:
        """Registered names of PX4's external modes by custom_mode (from AVAILABLE_MODES): the state names the
        mode PX4 flies by them from now on, and at once if it flies one now."""
        with self._cond:
            self._external_names = dict(names)
            self._rename_locked()

    def add_mode_namer(self, namer: ModeNamer) -> None:
        """A mode this process registered names itself (and says which PX4 mode it replaces): PX4's own list
        may not be read on this link (px4_zenoh has none), and only the owner knows what it replaces."""
        with self._cond:
            self._mode_namers = (*self._mode_namers, namer)
            self._rename_locked()

    def _external_fields(self, custom_mode: int) -> dict[str, Any]:
        """The state's mode_name and mode_replaces for ``custom_mode`` (under the state lock or not)."""
        for namer in self._mode_namers:
            try:
                named = namer(custom_mode)
            except Exception:   # noqa: BLE001 - a namer's bug must not stop the heartbeat's handling
                self.count("callback_errors")
                self.rlog.exception(f"namer{id(namer) % 64}", "%s mode namer %r raised", self._tag, namer)
                continue
            if named is not None:
                return {"mode_name": named[0], "mode_replaces": named[1]}
        return {"mode_name": self._external_names.get(custom_mode), "mode_replaces": None}

    def _rename_locked(self) -> None:
        s = self._state
        fields = self._external_fields(s.custom_mode) if s.connected else {"mode_name": None, "mode_replaces": None}
        if fields["mode_name"] != s.mode_name or fields["mode_replaces"] != s.mode_replaces:
            self._state = replace(s, **fields)
            self._cond.notify_all()

    # ----------------------------------------------------------------- lifecycle
    def start(self) -> None:
        if self._threads:
            return
        self._stop.clear()
        self._open()
        self._threads = [threading.Thread(target=self._rx_loop, name=f"{self._thread_prefix}-rx", daemon=True),
                         threading.Thread(target=self._tx_loop, name=f"{self._thread_prefix}-tx", daemon=True)]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        self._close()

    def _open(self) -> None:
        """Before the threads start: open what they read and write."""
        raise NotImplementedError

    def _close(self) -> None:
        """After the threads stopped: close what ``_open`` opened; safe to call twice."""
        raise NotImplementedError

    def _wake(self) -> None:
        """Wake a receive thread blocked on something other than ``_stop``."""

    def _rx_loop(self) -> None:
        raise NotImplementedError

    def _tick(self, now: float) -> None:
        """Send thread, every tick before the periodic hooks."""
        raise NotImplementedError

    def _tx_loop(self) -> None:
        period = 1.0 / self.tick_hz
        next_tick = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                self._tick(now)
                for hook in self._periodic:
                    hook()
            except Exception:  # the stream must survive anything (closed socket, bug)
                self.rlog.exception("tx", "%s stream thread error", self._tag)
            next_tick += period
            if next_tick < now:  # fell behind (suspended?): do not burst to catch up
                next_tick = now + period
            self._stop.wait(max(0.0, next_tick - time.monotonic()))

    # ----------------------------------------------------------------- state
    @property
    def connected(self) -> bool:
        return self._state.connected

    @property
    def state(self) -> Px4State:
        return self._state

    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.1))
        return True

    def notify(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def _on_vehicle_heartbeat(self, system_id: int, component_id: int, mode: str, armed: bool,
                              fields: dict[str, Any], locked: Callable[[], list[Event]] | None = None) -> None:
        """Receive thread: the vehicle's heartbeat (MAVLink HEARTBEAT, uORB vehicle_status). ``fields``
        go into the state as well; ``locked()`` runs under the state lock after the update and its
        events are emitted after connected / mode_changed / armed_changed."""
        now = time.monotonic()
        events: list[Event] = []
        with self._cond:
            old = self._state
            self._stats["heartbeats_received"] += 1
            self._state = replace(old, connected=True, system_id=system_id, component_id=component_id, mode=mode,
                                  armed=armed, last_heartbeat=now, heartbeats=old.heartbeats + 1, **fields)
            if not old.connected:
                reconnect = self._ever_connected
                if reconnect:
                    self._stats["reconnects"] += 1
                self._ever_connected = True
                events.append(("connected", {"system_id": system_id, "component_id": component_id,
                                             "reconnect": reconnect}))
            if old.mode != mode and old.heartbeats:
                events.append(("mode_changed", {"old": old.mode, "new": mode}))
                for hook in self._mode_hooks:
                    events.extend(hook(old.mode, mode))
            if old.armed != armed and old.heartbeats:
                events.append(("armed_changed", {"armed": armed}))
            if locked is not None:
                events.extend(locked())
            self._cond.notify_all()
        for name, details in events:
            self.emit(name, details)

    def _set_landed_state(self, landed_state: int) -> None:
        with self._cond:
            old = self._state.landed_state
            if old == landed_state:
                return
            self._state = replace(self._state, landed_state=landed_state)
            self._cond.notify_all()
        self.emit("landed_changed", {"old": old, "new": landed_state, "name": self._state.landed_state_name})

    def _check_watchdog(self, now: float) -> None:
        """Send thread: no heartbeat for ``heartbeat_timeout``: the vehicle is gone."""
        self._disconnect(now, timeout=self.heartbeat_timeout)

    def _disconnect(self, now: float, why: str | None = None, *, timeout: float | None = None) -> None:
        """The vehicle is gone (with ``timeout``: only if its heartbeat is older than that)."""
        with self._cond:
            s = self._state
            if not s.connected:
                return
            silent = now - (s.last_heartbeat if s.last_heartbeat is not None else now)
            if timeout is not None:
                if s.last_heartbeat is None or silent <= timeout:
                    return
                why = self._silence_reason(silent)
            self._state = replace(s, connected=False)
            self._stats["disconnects"] += 1
            self._cond.notify_all()
        self._on_disconnected()
        details: dict[str, Any] = {"system_id": s.system_id, "silent_s": silent}
        if why is not None:
            details["why"] = why
        self.emit("disconnected", details)

    def _silence_reason(self, silent: float) -> str | None:
        """The ``why`` of a watchdog disconnect (None: the event has no ``why``)."""
        return None

    def _on_disconnected(self) -> None:
        """After a disconnect, before its event."""

    # ----------------------------------------------------------------- commands
    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck:
        if not self._state.connected:
            raise NotConnected(command, None, f"{command_name(command)}: {self.not_connected_reason()}")
        return self._commands.run(command, params, timeout=timeout, retries=retries)

    def not_connected_reason(self) -> str:
        """The text a command refused for want of a vehicle carries; a backend that knows more says so."""
        return "no vehicle connected"

    def cancel_command(self, owner: int, why: str) -> bool:
        """Withdraw the command thread ``owner`` is waiting on (commands.CommandSender.cancel)."""
        return self._commands.cancel(owner, why)

    def _on_command_ack(self, target_system: int, target_component: int, command: int, result: int,
                        progress: int, result_param2: int) -> None:
        """Receive thread: an ACK answers our command only when it is addressed to our ids."""
        if target_system != self.source_system or target_component not in (0, self.source_component):
            self.count("unsolicited_acks")   # PX4's own, or an ACK to another client's command
            return
        outcome = self._commands.handle_ack(command, result, progress, result_param2)
        if outcome in ("duplicate", "unsolicited"):
            self.count(f"{outcome}_acks")

    # ----------------------------------------------------------------- telemetry cache
    def latest(self, kind: type[T]) -> T | None:
        sample: T | None = self._latest.get(kind)
        return sample

    def wait_sample(self, kind: type[T], timeout: float,
                    predicate: Callable[[T], bool] | None = None) -> T | None:
        since = time.monotonic()

        def fresh() -> bool:
            v = self._latest.get(kind)
            return v is not None and v.received_at >= since and (predicate is None or predicate(v))

        return self.latest(kind) if self.wait_until(fresh, timeout) else None

    def add_sample_listener(self, callback: Listener, kind: type | None = None) -> Listener:
        with self._listeners_lock:
            self._listeners.append((kind, callback))
        return callback

    def remove_sample_listener(self, callback: Listener) -> None:
        with self._listeners_lock:
            self._listeners = [(k, c) for k, c in self._listeners if c is not callback]

    def _publish(self, sample: Any) -> None:
        """Receive thread: store the (already validated) sample and call listeners."""
        self._latest[type(sample)] = sample
        self.notify()
        for kind, cb in list(self._listeners):
            if kind is None or isinstance(sample, kind):
                self.safe_call(cb, sample)

    # ----------------------------------------------------------------- counters, events, callbacks
    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._stats[key] += n

    def add_event_listener(self, callback: EventCallback) -> None:
        with self._lock:
            self._event_listeners.append(callback)

    def emit(self, name: str, details: dict[str, Any]) -> None:
        self._log.debug("%s event %s %s", self._tag, name, details)
        for cb in list(self._event_listeners):
            self.safe_call(cb, name, details)

    def safe_call(self, cb: Callable[..., Any], *args: Any) -> None:
        try:
            cb(*args)
        except Exception:
            self.count("callback_errors")
            self.rlog.exception(f"cb{id(cb) % 64}", "%s callback %r raised", self._tag, cb)
