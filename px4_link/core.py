"""LinkCore: the narrow core of the link, what every plugin sits on (see ``plugin.Core``).

It owns the connection (transport, MAVLink framing and signing), the ids (ours, the
vehicle's, the address lock), sending and commands, and the vehicle state from HEARTBEAT and
EXTENDED_SYS_STATE; the counters, the event bus, the telemetry cache with its listeners and
the two threads' lifecycle come from ``vehicle_core.VehicleCore`` (shared with PX4 over Zenoh).
It knows no plugin: plugins register message handlers, mode hooks and periodic hooks.

Threads: a receive thread parses bytes, dispatches to message handlers and telemetry
listeners; a send thread ticks at ``tick_hz``: our HEARTBEAT (1 Hz), the heartbeat
watchdog, then the periodic hooks (the offboard stream). Callbacks (listeners, hooks,
``on_event``) are invoked ON THOSE THREADS: keep them short and never block in them (no
link commands from inside a callback: a command waits for an ACK that the receive thread
would have to deliver). A callback that raises is logged (rate-limited) and counted in
``stats.callback_errors``.

Everything received is untrusted: see ``peer.py`` for the address lock; non-finite
telemetry never reaches listeners; an ACK only answers the command we are waiting for.

A transport that loses its wire (a serial device unplugged, PX4 rebooting on USB) says why in
``down_reason``: the receive thread turns that into ``link_down`` and ``disconnected`` at once (the
heartbeat watchdog would take ``heartbeat_timeout``), then ``link_up`` when bytes flow again; a
command meanwhile fails with that reason. On a serial port a ``BaudCheck`` names a wrong rate.

Raw frames (what a MAVLink router does with one port, e.g. the companion's tunnel to a QGC):
``add_frame_listener`` hands out the bytes of every frame accepted from the vehicle, as received;
``send_raw`` writes a frame built elsewhere, whole, between the link's own frames (every write, ours
or raw, is one ``write`` under one lock). On a serial port a raw frame yields to the link's own
traffic: it is refused (False) when the line is busy, so a chatty GCS delays a setpoint by
``RAW_BACKLOG_S`` at most.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from .commands import CommandSender
from .modes import decode_custom_mode
from .peer import PeerLock
from .plugin import MessageHandler
from .rates import BootWatch
from .serial_port import BaudCheck, SerialTransport
from .stats import LinkStats
from .telemetry import DECODERS, ExtendedSysState, is_finite_sample
from .transport import Address, Transport, open_transport
from .vehicle_core import VehicleCore
from .wire import Encoder, Parser, mavlink2, setup_signing

# The logger keeps the name it had before the core was split out of link.py: users filter on it.
log = logging.getLogger("px4_link.link")

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
# A raw frame goes out on a serial port only while the line's backlog (what was written and is still
# being clocked out, modelled from the baud rate) stays under both bounds: a few hundred bytes keep it
# far from the driver's buffer (4 kB on Linux UARTs), 30 ms keeps what it adds ahead of a setpoint
# small at any rate (57600 baud: 172 bytes).
RAW_BACKLOG_BYTES = 1024
RAW_BACKLOG_S = 0.03
# After the driver refused bytes (flow control, a stalled line) raw frames wait this long: the line
# is the link's own until it keeps up again.
RAW_PAUSE_S = 1.0

FrameListener = Callable[[bytes], None]
# (command, result) of an ACK addressed to us -> True when the filter's owner sent that command itself
AckFilter = Callable[[int, int], bool]


class LinkCore(VehicleCore):
    """Implements ``plugin.Core``; ``Px4Link`` builds one and hangs the plugins on it."""

    def __init__(self, connection: str, *, heartbeat_timeout: float, tick_hz: float,
                 source_system: int, source_component: int, target_system: int | None,
                 command_timeout: float, command_retries: int, signing_key: bytes | None,
                 baud: int) -> None:
        super().__init__(log=log, tag="px4_link", thread_prefix="px4link", counters=LinkStats.__dataclass_fields__,
                         heartbeat_timeout=heartbeat_timeout, tick_hz=tick_hz, source_system=source_system,
                         source_component=source_component)
        self.connection = connection
        self._signing_key = signing_key
        self._baud = baud
        self._last_statustext: tuple[float, str] | None = None
        self._peer = PeerLock(target_system)
        self._boot = BootWatch()
        self._any_handlers: list[MessageHandler] = []
        self._ack_filters: list[AckFilter] = []
        self._handlers: dict[str, list[MessageHandler]] = {}
        self._frame_listeners: tuple[FrameListener, ...] = ()   # replaced whole: added while running
        self._write_lock = threading.Lock()   # one frame at a time on the wire, ours or raw
        self._line_backlog = 0.0              # serial: bytes still to clock out (modelled), under _write_lock
        self._line_at = 0.0                   # when _line_backlog was last brought up to date
        self._raw_paused_until = 0.0
        self._tx_dropped_seen = 0

        self._transport: Transport | None = None
        self._baud_check: BaudCheck | None = None
        self._down_reason: str | None = None   # the transport's, as last seen by the receive thread
        self._encoder: Encoder | None = None
        self._next_heartbeat = 0.0
        self._parser = Parser()
        if self._signing_key is not None:
            for mav in self._parser.decoders:
                setup_signing(mav, self._signing_key, sign_outgoing=False)
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

    def add_ack_filter(self, ack_filter: AckFilter) -> None:
        """``ack_filter(command, result)`` on the receive thread for each COMMAND_ACK addressed to us, before
        the command sender: True claims it (a command a plugin sent without waiting). Register before ``start``."""
        self._ack_filters.append(ack_filter)

    def command_in_flight(self) -> int | None:
        """The command a caller of ``send_command`` waits for now, if any."""
        return self._commands.waiting_for

    def add_frame_listener(self, listener: FrameListener) -> None:
        """``listener(frame)`` on the receive thread with the bytes of every frame accepted from the
        vehicle, exactly as received (signature included), before any other handling. May be added
        while the link runs. It must be quick and must not raise (a raise is counted in callback_errors)."""
        with self._lock:
            self._frame_listeners = (*self._frame_listeners, listener)

    # ----------------------------------------------------------------- lifecycle
    def _open(self) -> None:
        self._transport = open_transport(self.connection, self._baud)
        t = self._transport
        self._baud_check = BaudCheck(t.url.device, t.baud) if isinstance(t, SerialTransport) else None
        self._encoder = Encoder(self._write, self.source_system, self.source_component)
        if self._signing_key is not None:
            setup_signing(self._encoder.mav, self._signing_key)
        self._next_heartbeat = 0.0

    def _close(self) -> None:
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
        t = self._transport
        if isinstance(t, SerialTransport):
            s.update(link_losses=t.losses, bytes_dropped_tx=t.tx_dropped)
        return LinkStats(**s)

    # ----------------------------------------------------------------- sending
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
        with self._write_lock:
            t.write(data)
            self._on_line(t, len(data))
        with self._lock:
            self._stats["bytes_sent"] += len(data)
            self._stats["messages_sent"] += 1

    def send_raw(self, frame: bytes) -> bool:
        """Write ``frame`` (one whole MAVLink frame built elsewhere, e.g. a GCS's) to the vehicle as it
        is, never interleaved with the link's own frames; thread-safe. False, and nothing written, when
        it cannot go whole now: no wire (not started, serial device gone) or, on a serial port, a busy
        line (see ``RAW_BACKLOG_BYTES``): the caller drops it, nothing is queued. Counted in bytes_sent."""
        t = self._transport
        if t is None or t.down_reason is not None:
            return False
        with self._write_lock:
            if not isinstance(t, SerialTransport):
                t.write(frame)
            elif not self._line_free_for(t, len(frame)):
                return False
            else:
                before = t.tx_dropped
                t.write(frame)
                self._on_line(t, len(frame))
                if t.tx_dropped != before:
                    return False   # the driver took part of it at most: a broken frame, PX4 resyncs on the next
        self.count("bytes_sent", len(frame))
        return True

    def _on_line(self, t: Transport, n: int) -> None:
        """Under _write_lock, after ``n`` bytes were written: the serial line's modelled backlog."""
        if isinstance(t, SerialTransport):
            self._drain_line(t.baud)
            self._line_backlog += n

    def _drain_line(self, baud: int) -> None:
        now = time.monotonic()
        # 10 bits a byte on the wire (start, 8 data, stop)
        self._line_backlog = max(0.0, self._line_backlog - (now - self._line_at) * baud / 10.0)
        self._line_at = now

    def _line_free_for(self, t: SerialTransport, n: int) -> bool:
        """Under _write_lock: may ``n`` raw bytes go on the serial line now without holding up the link's own?"""
        now = time.monotonic()
        if t.tx_dropped != self._tx_dropped_seen:   # the driver refused bytes since: the line is behind
            self._tx_dropped_seen = t.tx_dropped
            self._raw_paused_until = now + RAW_PAUSE_S
        if now < self._raw_paused_until:
            return False
        self._drain_line(t.baud)
        # A frame longer than the bound (a 280-byte one at 57600 baud) still goes on an idle line.
        return self._line_backlog + n <= max(min(RAW_BACKLOG_BYTES, RAW_BACKLOG_S * t.baud / 10.0), n)

    def _send_command_long(self, command: int, params: Any, confirmation: int) -> None:
        sysid, compid = self.vehicle_ids()
        self.send_message(self.encoder().command_long_encode(sysid, compid, command, confirmation, *params))

    def _send_heartbeat(self) -> None:
        self.send_message(self.encoder().heartbeat_encode(
            MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE))
        self.count("heartbeats_sent")

    # ----------------------------------------------------------------- threads
    def _tick(self, now: float) -> None:
        if now >= self._next_heartbeat:
            self._send_heartbeat()
            self._next_heartbeat = now + 1.0
        self._check_watchdog(now)

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
            if t.down_reason != self._down_reason:
                self._link_changed(t.down_reason)
            if got is None:
                continue
            data, addr = got
            try:
                for m in self._parser.feed(data, datagram=t.datagram):
                    self._accept(m, addr)
                if addr is not None and addr == self._peer.address:
                    t.set_peer(addr)   # answer the locked vehicle address only
                if self._baud_check is not None:
                    self._check_baud(self._baud_check)
            except Exception:
                self.rlog.exception("handle", "px4_link error handling received data")

    def _link_changed(self, why: str | None) -> None:
        """Receive thread: the transport lost its wire (``why``) or has it back (None)."""
        was, self._down_reason = self._down_reason, why
        if why is None:
            self.emit("link_up", {"connection": self.connection})
            return
        if was is None:   # a new loss, not a failed reopen: its reason is what the GCS is told
            self._log.warning("px4_link: %s", why)
        self.emit("link_down", {"why": why})
        self._disconnect(time.monotonic(), why=why)

    def _check_baud(self, check: BaudCheck) -> None:
        verdict = check.update(self._parser.bytes_received, self._parser.messages)
        if verdict is not None:
            self.count("baud_mismatches")
            self._log.warning("px4_link: %s", verdict)
            self.emit("baud_mismatch", {"why": verdict})

    def not_connected_reason(self) -> str:
        """Why no vehicle is connected, for a refused command: the wire's state first."""
        if self._down_reason is not None:
            return self._down_reason
        check = self._baud_check
        if check is not None and check.suspect is not None:
            return check.suspect
        return super().not_connected_reason()

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
        for listener in self._frame_listeners:
            self.safe_call(listener, bytes(m.get_msgbuf()))
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
            self._set_landed_state(sample.landed_state)
        self._publish(sample)

    def _on_ack(self, m: Any) -> None:
        if m.target_system == self.source_system and m.target_component in (0, self.source_component):
            for claimed in self._ack_filters:
                if claimed(m.command, m.result):
                    return
        self._on_command_ack(m.target_system, m.target_component, m.command, m.result, getattr(m, "progress", 0),
                             getattr(m, "result_param2", 0))

    def _on_heartbeat(self, m: Any) -> None:
        custom = bool(m.base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        mode = decode_custom_mode(m.custom_mode) if custom else "UNKNOWN"
        self._on_vehicle_heartbeat(
            m.get_srcSystem(), m.get_srcComponent(), mode, bool(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
            {**(self._external_fields(m.custom_mode) if custom else {"mode_name": None, "mode_replaces": None}),
             "custom_mode": m.custom_mode, "base_mode": m.base_mode, "system_status": m.system_status,
             "autopilot": m.autopilot, "vehicle_type": m.type})

    def _on_reboot(self) -> None:
        self.count("reboots")
        self.emit("rebooted", {"system_id": self._state.system_id})

    def _on_disconnected(self) -> None:
        self._boot.reset()

    def _recent_statustext(self) -> str:
        st = self._last_statustext
        if st is not None and time.monotonic() - st[0] < 1.0:
            return f"vehicle says: {st[1]}"
        return ""
