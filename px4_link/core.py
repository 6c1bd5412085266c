"""LinkCore: the narrow core of the link, what every plugin sits on (see ``plugin.Core``).

It owns the connection (transport, MAVLink framing and signing), the ids (ours, the
vehicle's, the address lock), sending and commands, the vehicle state from HEARTBEAT and
EXTENDED_SYS_STATE, the counters, the event bus, the telemetry cache with its listeners,
and two threads. It knows no plugin: plugins register message handlers, mode hooks and
periodic hooks.

Threads: a receive thread parses bytes, dispatches to message handlers and telemetry
listeners; a send thread ticks at ``tick_hz``: our HEARTBEAT (1 Hz), the heartbeat
watchdog, then the periodic hooks (the offboard stream). Callbacks (listeners, hooks,
``on_event``) are invoked ON THOSE THREADS: keep them short and never block in them (no
link commands from inside a callback: a command waits for an ACK that the receive thread
would have to deliver). A callback that raises is logged (rate-limited) and counted in
``stats.callback_errors``.

Everything received is untrusted: see ``peer.py`` for the address lock; non-finite
telemetry never reaches listeners; an ACK only answers the command we are waiting for.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any, TypeVar

from . import commands as cmds
from .commands import CommandAck, CommandSender, NotConnected
from .modes import decode_custom_mode
from .peer import PeerLock
from .plugin import Event, EventCallback, Listener, MessageHandler, ModeHook, PeriodicHook
from .ratelimit import RateLimitedLog
from .rates import BootWatch
from .stats import LinkStats
from .telemetry import DECODERS, ExtendedSysState, Px4State, is_finite_sample
from .transport import Address, Transport, open_transport
from .wire import Encoder, Parser, mavlink2, setup_signing

# The logger keeps the name it had before the core was split out of link.py: users filter on it.
log = logging.getLogger("px4_link.link")

T = TypeVar("T")

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1


class LinkCore:
    """Implements ``plugin.Core``; ``Px4Link`` builds one and hangs the plugins on it."""

    def __init__(self, connection: str, *, heartbeat_timeout: float, tick_hz: float,
                 source_system: int, source_component: int, target_system: int | None,
                 command_timeout: float, command_retries: int, signing_key: bytes | None,
                 baud: int) -> None:
        self.connection = connection
        self.heartbeat_timeout = heartbeat_timeout
        self.tick_hz = tick_hz
        self.source_system = source_system
        self.source_component = source_component
        self._signing_key = signing_key
        self._baud = baud
        self._event_listeners: list[EventCallback] = []
        self.rlog = RateLimitedLog(log, burst=1, interval=5.0)

        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._state = Px4State()
        self._stats: dict[str, int] = {f: 0 for f in LinkStats.__dataclass_fields__}
        self._ever_connected = False
        self._last_statustext: tuple[float, str] | None = None
        self._peer = PeerLock(target_system)
        self._boot = BootWatch()

        self._latest: dict[type, Any] = {}
        self._listeners: list[tuple[type | None, Listener]] = []
        self._listeners_lock = threading.Lock()
        self._any_handlers: list[MessageHandler] = []
        self._handlers: dict[str, list[MessageHandler]] = {}
        self._mode_hooks: list[ModeHook] = []
        self._periodic: list[PeriodicHook] = []

        self._transport: Transport | None = None
        self._encoder: Encoder | None = None
        self._parser = Parser()
        if self._signing_key is not None:
            setup_signing(self._parser.mav, self._signing_key, sign_outgoing=False)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._commands = CommandSender(self._send_command_long, command_timeout, command_retries,
                                       context=self._recent_statustext)

    # ----------------------------------------------------------------- hooks
    def add_message_handler(self, mtype: str | None, handler: MessageHandler) -> None:
        """``handler(msg)`` on the receive thread for each accepted ``mtype`` (None: all,
        before any other handling). Register before ``start``."""
        if mtype is None:
            self._any_handlers.append(handler)
        else:
            self._handlers.setdefault(mtype, []).append(handler)

    def add_mode_hook(self, hook: ModeHook) -> None:
        """``hook(old, new)`` under the state lock when PX4's mode changes; the events it
        returns are emitted right after ``mode_changed``."""
        self._mode_hooks.append(hook)

    def add_periodic(self, hook: PeriodicHook) -> None:
        """``hook()`` on the send thread at every tick, after the heartbeat and watchdog."""
        self._periodic.append(hook)

    # ----------------------------------------------------------------- lifecycle
    def start(self) -> None:
        if self._threads:
            return
        self._stop.clear()
        self._transport = open_transport(self.connection, self._baud)
        self._encoder = Encoder(self._write, self.source_system, self.source_component)
        if self._signing_key is not None:
            setup_signing(self._encoder.mav, self._signing_key)
        self._threads = [threading.Thread(target=self._rx_loop, name="px4link-rx", daemon=True),
                         threading.Thread(target=self._tx_loop, name="px4link-tx", daemon=True)]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    @property
    def local_port(self) -> int | None:
        addr = self._transport.local_address if self._transport else None
        return addr[1] if addr else None

    @property
    def vehicle_address(self) -> Address | None:
        return self._peer.address

    # ----------------------------------------------------------------- state
    @property
    def connected(self) -> bool:
        return self._state.connected

    @property
    def state(self) -> Px4State:
        return self._state

    @property
    def can_send(self) -> bool:
        return self._transport is not None and self._state.connected

    @property
    def stats(self) -> LinkStats:
        with self._lock:
            s = dict(self._stats)
        p = self._parser
        s.update(bytes_received=p.bytes_received, messages_received=p.messages,
                 garbage_bytes=p.bad_bytes, bad_frames=p.bad_frames, crc_errors=p.crc_errors,
                 unknown_messages=p.unknown_messages, bad_signatures=p.bad_signatures,
                 commands_sent=self._commands.sent, command_retries=self._commands.retried)
        return LinkStats(**s)

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

    def add_event_listener(self, callback: EventCallback) -> None:
        with self._lock:
            self._event_listeners.append(callback)

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

    # ----------------------------------------------------------------- sending
    def cancel_command(self, owner: int, why: str) -> bool:
        """Withdraw the COMMAND_LONG thread ``owner`` is waiting on (commands.CommandSender.cancel)."""
        return self._commands.cancel(owner, why)

    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck:
        if not self._state.connected:
            raise NotConnected(command, None, f"{cmds.command_name(command)}: no vehicle connected")
        return self._commands.run(command, params, timeout=timeout, retries=retries)

    def encoder(self) -> Encoder:
        if self._encoder is None:
            raise RuntimeError("Px4Link is not started (use it as a context manager)")
        return self._encoder

    def send_message(self, msg: Any) -> None:
        self.encoder().send(msg)

    def vehicle_ids(self) -> tuple[int, int]:
        s = self._state
        return (s.system_id or self._peer.target_system or 1, s.component_id or 1)

    def _write(self, data: bytes) -> None:
        t = self._transport
        if t is None:
            return
        t.write(data)
        with self._lock:
            self._stats["bytes_sent"] += len(data)
            self._stats["messages_sent"] += 1

    def _send_command_long(self, command: int, params: Any, confirmation: int) -> None:
        sysid, compid = self.vehicle_ids()
        self.send_message(self.encoder().command_long_encode(sysid, compid, command, confirmation, *params))

    def _send_heartbeat(self) -> None:
        self.send_message(self.encoder().heartbeat_encode(
            MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE))
        self.count("heartbeats_sent")

    # ----------------------------------------------------------------- threads
    def _tx_loop(self) -> None:
        period = 1.0 / self.tick_hz
        next_tick = time.monotonic()
        next_hb = next_tick
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_hb:
                    self._send_heartbeat()
                    next_hb = now + 1.0
                self._check_watchdog(now)
                for hook in self._periodic:
                    hook()
            except Exception:  # the stream must survive anything (closed socket, bug)
                self.rlog.exception("tx", "px4_link stream thread error")
            next_tick += period
            if next_tick < now:  # fell behind (suspended?): do not burst to catch up
                next_tick = now + period
            self._stop.wait(max(0.0, next_tick - time.monotonic()))

    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            t = self._transport
            if t is None:
                break
            try:
                got = t.recv(0.1)
            except Exception:
                if self._stop.is_set():
                    break
                self.rlog.exception("recv", "px4_link receive error")
                self._stop.wait(0.1)
                continue
            if got is None:
                continue
            data, addr = got
            try:
                for m in self._parser.feed(data, datagram=t.datagram):
                    self._accept(m, addr)
                if addr is not None and addr == self._peer.address:
                    t.set_peer(addr)   # answer the locked vehicle address only
            except Exception:
                self.rlog.exception("handle", "px4_link error handling received data")

    # ----------------------------------------------------------------- receiving
    def _accept(self, m: Any, addr: Address | None) -> None:
        silent = not self._state.connected
        verdict = self._peer.classify(m, addr, silent)
        if verdict == "other":
            self.count("other_system_messages")
            return
        if verdict == "spoofed":
            self.count("spoofed_frames")
            self.rlog.warning("spoof", "px4_link: frame claiming system %d from %s, vehicle is "
                                       "at %s: dropped", m.get_srcSystem(), addr, self._peer.address)
            return
        for handler in self._any_handlers:
            handler(m)
        self._handle(m)

    def _handle(self, m: Any) -> None:
        mtype = m.get_type()
        if mtype == "HEARTBEAT":
            if m.get_srcComponent() == 1 and m.autopilot != MAV_AUTOPILOT_INVALID:
                self._on_heartbeat(m)
            return
        if mtype == "COMMAND_ACK":
            self._on_ack(m)
        elif mtype == "COMMAND_LONG":
            # PX4's own requests to other components (gimbal manager on LAND): not for us.
            self.count("vehicle_commands_ignored")
        elif mtype == "STATUSTEXT":
            text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
            text = text.rstrip("\x00")
            with self._lock:
                self._last_statustext = (time.monotonic(), text)
            self.emit("statustext", {"severity": m.severity, "text": text})
        elif mtype in ("ATTITUDE", "SYSTEM_TIME"):
            if self._boot.rebooted(m.time_boot_ms):
                self._on_reboot()
        for handler in self._handlers.get(mtype, ()):
            handler(m)
        decoder = DECODERS.get(mtype)
        if decoder is None:
            return
        sample = decoder(m)
        if not is_finite_sample(sample):
            self.count("nonfinite_telemetry")
            self.rlog.warning("nonfinite", "px4_link: dropped %s with non-finite values", mtype)
            return
        if isinstance(sample, ExtendedSysState):
            self._on_landed_state(sample.landed_state)
        self._publish(sample)

    def _on_ack(self, m: Any) -> None:
        if m.target_system != self.source_system or m.target_component not in (0, self.source_component):
            self.count("unsolicited_acks")   # an ACK to someone else's command
            return
        outcome = self._commands.handle_ack(m.command, m.result, getattr(m, "progress", 0),
                                            getattr(m, "result_param2", 0))
        if outcome == "duplicate":
            self.count("duplicate_acks")
        elif outcome == "unsolicited":
            self.count("unsolicited_acks")

    def _on_heartbeat(self, m: Any) -> None:
        now = time.monotonic()
        custom = bool(m.base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        mode = decode_custom_mode(m.custom_mode) if custom else "UNKNOWN"
        armed = bool(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        events: list[Event] = []
        with self._cond:
            old = self._state
            self._stats["heartbeats_received"] += 1
            self._state = replace(old, connected=True, system_id=m.get_srcSystem(),
                                  component_id=m.get_srcComponent(), mode=mode,
                                  custom_mode=m.custom_mode, base_mode=m.base_mode, armed=armed,
                                  system_status=m.system_status, autopilot=m.autopilot,
                                  vehicle_type=m.type, last_heartbeat=now,
                                  heartbeats=old.heartbeats + 1)
            if not old.connected:
                reconnect = self._ever_connected
                if reconnect:
                    self._stats["reconnects"] += 1
                self._ever_connected = True
                events.append(("connected", {"system_id": m.get_srcSystem(),
                                             "component_id": m.get_srcComponent(),
                                             "reconnect": reconnect}))
            if old.mode != mode and old.heartbeats:
                events.append(("mode_changed", {"old": old.mode, "new": mode}))
                for hook in self._mode_hooks:
                    events.extend(hook(old.mode, mode))
            if old.armed != armed and old.heartbeats:
                events.append(("armed_changed", {"armed": armed}))
            self._cond.notify_all()
        for name, details in events:
            self.emit(name, details)

    def _on_reboot(self) -> None:
        self.count("reboots")
        self.emit("rebooted", {"system_id": self._state.system_id})

    def _on_landed_state(self, landed_state: int) -> None:
        with self._cond:
            old = self._state.landed_state
            if old == landed_state:
                return
            self._state = replace(self._state, landed_state=landed_state)
            self._cond.notify_all()
        self.emit("landed_changed", {"old": old, "new": landed_state,
                                     "name": self._state.landed_state_name})

    def _check_watchdog(self, now: float) -> None:
        with self._cond:
            s = self._state
            if not s.connected or s.last_heartbeat is None:
                return
            silent = now - s.last_heartbeat
            if silent <= self.heartbeat_timeout:
                return
            self._state = replace(s, connected=False)
            self._stats["disconnects"] += 1
            self._boot.reset()
            self._cond.notify_all()
        self.emit("disconnected", {"system_id": s.system_id, "silent_s": silent})

    def _recent_statustext(self) -> str:
        st = self._last_statustext
        if st is not None and time.monotonic() - st[0] < 1.0:
            return f"vehicle says: {st[1]}"
        return ""

    # ----------------------------------------------------------------- callbacks
    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._stats[key] += n

    def emit(self, name: str, details: dict[str, Any]) -> None:
        log.debug("px4_link event %s %s", name, details)
        for cb in list(self._event_listeners):
            self.safe_call(cb, name, details)

    def safe_call(self, cb: Callable[..., Any], *args: Any) -> None:
        try:
            cb(*args)
        except Exception:
            self.count("callback_errors")
            self.rlog.exception(f"cb{id(cb) % 64}", "px4_link callback %r raised", cb)
