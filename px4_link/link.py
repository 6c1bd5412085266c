"""Px4Link: the companion's MAVLink connection to PX4.

Threads: a receive thread parses bytes and dispatches telemetry, and a stream thread
sends our HEARTBEAT (1 Hz), streams the latest offboard setpoint at a fixed rate and runs
the heartbeat watchdog. Callbacks (telemetry listeners and ``on_event``) are invoked ON
THOSE THREADS: keep them short and never block in them (no link commands from inside a
callback: a command waits for an ACK that the receive thread would have to deliver).
A callback that raises is logged and counted in ``stats.callback_errors``; it never stops
the link.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import replace
from typing import Any, Callable, TypeVar

from . import commands as cmds
from .commands import CommandAck, CommandFailed, CommandSender, NotConnected
from .modes import decode_custom_mode, mode_to_main_sub, normalize_mode_name
from .setpoints import Geofence, Setpoint, SetpointRejected, SetpointValidator, \
    mavlink_fields
from .stats import LinkStats
from .telemetry import DECODERS, ExtendedSysState, LocalPosition, GlobalPosition, VehicleState
from .transport import Transport, open_transport
from .wire import Encoder, Parser, float_bits_to_int, int_to_float_bits, mavlink2, message_id

log = logging.getLogger(__name__)

T = TypeVar("T")
EventCallback = Callable[[str, dict[str, Any]], None]
Listener = Callable[[Any], None]

MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
ARM_FORCE_MAGIC = 21196  # PX4: param2 == 21196 skips arming/disarming checks
_NON_VEHICLE_TYPES = {MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER, 26, 27, 30, 31}  # gimbal, adsb, camera...

_DEFAULT_GEOFENCE = Geofence()


class Px4Link:
    """MAVLink adapter to PX4. Use as a context manager::

        with Px4Link("udpin:0.0.0.0:14540") as link:
            link.wait_connected(10)
            link.arm(); link.takeoff(5)

    Events delivered to ``on_event(name, details)``: connected, disconnected, mode_changed,
    armed_changed, landed_changed, offboard_lost, setpoint_rejected, statustext.
    """

    def __init__(self, connection: str = "udpin:0.0.0.0:14540", *,
                 heartbeat_timeout: float = 3.0,
                 setpoint_rate_hz: float = 20.0,
                 geofence: Geofence | None = _DEFAULT_GEOFENCE,
                 max_speed: float | None = 10.0,
                 source_system: int = 245,
                 source_component: int = 191,  # MAV_COMP_ID_ONBOARD_COMPUTER
                 target_system: int | None = None,
                 on_event: EventCallback | None = None,
                 command_timeout: float = 1.0,
                 command_retries: int = 3,
                 baud: int = 921600) -> None:
        if setpoint_rate_hz < 10.0:
            # PX4 needs > 2 Hz; 10 Hz keeps a margin for a lossy serial/UDP hop.
            raise ValueError("setpoint_rate_hz must be >= 10")
        self.connection = connection
        self.heartbeat_timeout = heartbeat_timeout
        self.setpoint_rate_hz = setpoint_rate_hz
        self.source_system = source_system
        self.source_component = source_component
        self._target_system = target_system
        self._baud = baud
        self._validator = SetpointValidator(geofence, max_speed)
        self._event_listeners: list[EventCallback] = [on_event] if on_event else []
        self._listeners: list[tuple[type | None, Listener]] = []

        self._lock = threading.RLock()
        self._state = VehicleState()
        self._latest: dict[type, Any] = {}
        self._telemetry_cond = threading.Condition(self._lock)
        self._stats: dict[str, int] = {f: 0 for f in LinkStats.__dataclass_fields__}
        self._ever_connected = False
        self._last_statustext: tuple[float, str] | None = None
        self._param_waiters: dict[str, list[Any]] = {}

        self._setpoint: Setpoint | None = None
        self._streaming = False
        self._stream_started: float | None = None
        self._offboard_active = False
        self._leaving_offboard = False

        self._transport: Transport | None = None
        self._encoder: Encoder | None = None
        self._parser = Parser()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._t0 = time.monotonic()
        self._commands = CommandSender(self._send_command_long, command_timeout, command_retries,
                                       context=self._recent_statustext)

    # ----------------------------------------------------------------- lifecycle
    def start(self) -> "Px4Link":
        if self._threads:
            return self
        self._stop.clear()
        self._transport = open_transport(self.connection, self._baud)
        self._encoder = Encoder(self._write, self.source_system, self.source_component)
        self._threads = [threading.Thread(target=self._rx_loop, name="px4link-rx", daemon=True),
                         threading.Thread(target=self._tx_loop, name="px4link-tx", daemon=True)]
        for t in self._threads:
            t.start()
        return self

    def stop(self) -> None:
        """Stop both threads and close the transport; safe to call twice."""
        self._stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    close = stop

    def __enter__(self) -> "Px4Link":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    @property
    def local_port(self) -> int | None:
        """Port we are bound to (useful with ``udpin:127.0.0.1:0``)."""
        addr = self._transport.local_address if self._transport else None
        return addr[1] if addr else None

    # ----------------------------------------------------------------- state
    @property
    def connected(self) -> bool:
        return self._state.connected

    @property
    def state(self) -> VehicleState:
        return self._state

    @property
    def mode(self) -> str:
        return self._state.mode

    @property
    def armed(self) -> bool:
        return self._state.armed

    @property
    def system_id(self) -> int | None:
        return self._state.system_id

    @property
    def stats(self) -> LinkStats:
        with self._lock:
            s = dict(self._stats)
        p = self._parser
        s.update(bytes_received=p.bytes_received, messages_received=p.messages,
                 garbage_bytes=p.bad_bytes, bad_frames=p.bad_frames, crc_errors=p.crc_errors,
                 unknown_messages=p.unknown_messages, commands_sent=self._commands.sent,
                 command_retries=self._commands.retried)
        return LinkStats(**s)

    @property
    def setpoint(self) -> Setpoint | None:
        return self._setpoint

    @property
    def streaming(self) -> bool:
        return self._streaming

    @property
    def offboard_active(self) -> bool:
        return self._offboard_active

    def wait_connected(self, timeout: float = 10.0) -> bool:
        """Block until a vehicle heartbeat is seen; False on timeout."""
        return self._wait(lambda: self._state.connected, timeout)

    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Poll ``predicate`` (woken by every telemetry/heartbeat) until true or timeout."""
        return self._wait(predicate, timeout)

    def _wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self._telemetry_cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._telemetry_cond.wait(min(left, 0.1))
        return True

    # ----------------------------------------------------------------- telemetry
    def latest(self, kind: type[T]) -> T | None:
        """Most recent telemetry of that dataclass type (e.g. ``link.latest(Imu)``)."""
        return self._latest.get(kind)

    def wait_telemetry(self, kind: type[T], timeout: float = 5.0,
                       predicate: Callable[[T], bool] | None = None) -> T | None:
        """Wait for telemetry of ``kind`` newer than now (matching ``predicate``)."""
        since = time.monotonic()

        def fresh() -> bool:
            v = self._latest.get(kind)
            return v is not None and v.received_at >= since and (predicate is None or predicate(v))

        return self._latest.get(kind) if self._wait(fresh, timeout) else None

    def add_listener(self, callback: Listener, kind: type | None = None) -> Listener:
        """Call ``callback(sample)`` for each telemetry sample (of ``kind`` only, if given).
        Runs on the receive thread."""
        with self._lock:
            self._listeners.append((kind, callback))
        return callback

    def remove_listener(self, callback: Listener) -> None:
        with self._lock:
            self._listeners = [(k, c) for k, c in self._listeners if c is not callback]

    def add_event_listener(self, callback: EventCallback) -> None:
        with self._lock:
            self._event_listeners.append(callback)

    # ----------------------------------------------------------------- commands
    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck:
        """COMMAND_LONG to the vehicle; returns the ACK or raises a CommandError subclass."""
        if not self._state.connected:
            raise NotConnected(command, None, f"{cmds.command_name(command)}: no vehicle connected")
        return self._commands.run(command, params, timeout=timeout, retries=retries)

    def arm(self) -> CommandAck:
        return self.send_command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def disarm(self, force: bool = False) -> CommandAck:
        """Disarm; PX4 refuses in the air unless ``force`` (motors stop: the vehicle falls)."""
        return self.send_command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                 ARM_FORCE_MAGIC if force else 0)

    def set_mode(self, name: str, confirm_timeout: float = 3.0) -> CommandAck:
        """MAV_CMD_DO_SET_MODE with PX4 custom main/sub mode, then wait until the heartbeat
        shows it (an ACK alone does not guarantee the switch stuck)."""
        canonical = normalize_mode_name(name)
        main, sub = mode_to_main_sub(canonical)
        ack = self.send_command(mavlink2.MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                main, sub)
        if confirm_timeout > 0 and not self._wait(lambda: self._state.mode == canonical,
                                                  confirm_timeout):
            raise CommandFailed(mavlink2.MAV_CMD_DO_SET_MODE, ack.result,
                                f"mode {canonical} accepted but heartbeat still shows "
                                f"{self._state.mode} after {confirm_timeout:g} s")
        return ack

    def takeoff(self, altitude: float | None = None) -> CommandAck:
        """MAV_CMD_NAV_TAKEOFF to ``altitude`` m above home (PX4's MIS_TAKEOFF_ALT if None).
        PX4 wants param7 as AMSL altitude, so home's AMSL altitude comes from
        GLOBAL_POSITION_INT (alt - relative_alt)."""
        amsl = math.nan
        if altitude is not None:
            gp = self.latest(GlobalPosition) or self.wait_telemetry(GlobalPosition, 2.0)
            if gp is None:
                raise CommandFailed(mavlink2.MAV_CMD_NAV_TAKEOFF, None,
                                    "takeoff altitude needs GLOBAL_POSITION_INT to know home AMSL")
            amsl = gp.alt_m - gp.relative_alt_m + altitude
        return self.send_command(mavlink2.MAV_CMD_NAV_TAKEOFF, -1, 0, 0, math.nan, math.nan,
                                 math.nan, amsl)

    def land(self) -> CommandAck:
        return self.send_command(mavlink2.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan,
                                 math.nan, math.nan)

    def rtl(self) -> CommandAck:
        return self.send_command(mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    def hold(self) -> CommandAck:
        return self.set_mode("AUTO.LOITER")

    def request_message_interval(self, message: str | int, hz: float) -> CommandAck:
        """MAV_CMD_SET_MESSAGE_INTERVAL; hz <= 0 disables the stream."""
        interval_us = 1e6 / hz if hz > 0 else -1
        return self.send_command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, message_id(message),
                                 interval_us)

    # ----------------------------------------------------------------- parameters
    def get_param(self, name: str, timeout: float = 1.0, retries: int = 3) -> float | int:
        """PARAM_REQUEST_READ; INT32 params decoded from PX4's bytewise encoding."""
        def request() -> None:
            self._send(self._enc().param_request_read_encode(
                self._vehicle_ids()[0], self._vehicle_ids()[1], name.encode(), -1))
        return self._param_exchange(name, request, timeout, retries)

    def set_param(self, name: str, value: float | int, timeout: float = 1.0,
                  retries: int = 3) -> float | int:
        """PARAM_SET; ints are sent as MAV_PARAM_TYPE_INT32 (bytewise), floats as REAL32.
        Returns the value the vehicle echoes back."""
        if isinstance(value, bool) or isinstance(value, int):
            ptype = mavlink2.MAV_PARAM_TYPE_INT32
            wire = int_to_float_bits(int(value))
        else:
            ptype = mavlink2.MAV_PARAM_TYPE_REAL32
            wire = float(value)

        def request() -> None:
            sysid, compid = self._vehicle_ids()
            self._send(self._enc().param_set_encode(sysid, compid, name.encode(), wire, ptype))
        got = self._param_exchange(name, request, timeout, retries)
        if (ptype == mavlink2.MAV_PARAM_TYPE_INT32 and got != int(value)) or \
                (ptype == mavlink2.MAV_PARAM_TYPE_REAL32 and not math.isclose(got, value,
                                                                              rel_tol=1e-6)):
            raise CommandFailed(0, None, f"PARAM_SET {name}={value}: vehicle reports {got}")
        return got

    def _param_exchange(self, name: str, request: Callable[[], None], timeout: float,
                        retries: int) -> float | int:
        if not self._state.connected:
            raise NotConnected(0, None, f"param {name}: no vehicle connected")
        slot: list[Any] = []
        with self._lock:
            self._param_waiters.setdefault(name, []).append(slot)
        try:
            for _ in range(retries + 1):
                request()
                if self._wait(lambda: bool(slot), timeout):
                    return slot[0]
            raise cmds.CommandTimeout(0, None, f"param {name}: no PARAM_VALUE after "
                                               f"{retries + 1} attempts")
        finally:
            with self._lock:
                waiters = self._param_waiters.get(name, [])
                if slot in waiters:
                    waiters.remove(slot)

    # ----------------------------------------------------------------- offboard
    def set_setpoint(self, sp: Setpoint) -> None:
        """Validate and store the setpoint the stream thread sends at setpoint_rate_hz;
        the first one starts the stream. Raises SetpointRejected (nothing is sent)."""
        now = time.monotonic()
        lp = self.latest(LocalPosition)
        vehicle_pos = lp.position if lp is not None and now - lp.received_at < 1.0 else None
        try:
            self._validator.check(sp, now, vehicle_pos)
        except SetpointRejected as e:
            with self._lock:
                self._stats["setpoints_rejected"] += 1
            self._emit("setpoint_rejected", {"setpoint": sp, "reason": e.reason, "message": str(e)})
            raise
        self._validator.accept(sp, now)
        with self._lock:
            self._setpoint = sp
            if not self._streaming:
                self._streaming = True
                self._stream_started = now
        # Forward at once rather than waiting for the next tick: setpoint age matters.
        self._send_setpoint(sp)

    def stop_setpoint_stream(self) -> None:
        """Stop streaming (the latest setpoint is kept). In OFFBOARD this makes PX4 fail
        safe after COM_OF_LOSS_T, which is what the link reports as ``offboard_lost``."""
        with self._lock:
            self._streaming = False
            self._stream_started = None

    def start_offboard(self, prestream_s: float = 1.2, confirm_timeout: float = 3.0) -> CommandAck:
        """Make sure setpoints have streamed for ``prestream_s`` (PX4 wants ~1 s of
        > 2 Hz before it accepts OFFBOARD; the default adds a margin for transit and
        clock granularity), then switch to OFFBOARD."""
        with self._lock:
            if self._setpoint is None:
                raise SetpointRejected("no_setpoint", "start_offboard needs a setpoint first "
                                                      "(call set_setpoint)")
            if not self._streaming:
                self._streaming = True
                self._stream_started = time.monotonic()
            started = self._stream_started or time.monotonic()
        wait = prestream_s - (time.monotonic() - started)
        if wait > 0:
            self._stop.wait(wait)
        ack = self.set_mode("OFFBOARD", confirm_timeout)
        with self._lock:
            self._offboard_active = True
        return ack

    def stop_offboard(self, mode: str | None = "AUTO.LOITER") -> CommandAck | None:
        """Leave OFFBOARD cleanly: switch to ``mode`` while still streaming (so PX4 never
        sees a loss), then stop the stream. ``mode=None`` only stops the stream."""
        ack = None
        with self._lock:
            self._leaving_offboard = True
        try:
            if mode is not None and self._state.connected:
                ack = self.set_mode(mode)
        finally:
            with self._lock:
                self._offboard_active = False
                self._leaving_offboard = False
            self.stop_setpoint_stream()
        return ack

    # ----------------------------------------------------------------- sending
    def _enc(self) -> Encoder:
        if self._encoder is None:
            raise RuntimeError("Px4Link is not started (use it as a context manager)")
        return self._encoder

    def _write(self, data: bytes) -> None:
        t = self._transport
        if t is None:
            return
        t.write(data)
        with self._lock:
            self._stats["bytes_sent"] += len(data)
            self._stats["messages_sent"] += 1

    def _send(self, msg: Any) -> None:
        self._enc().send(msg)

    def _vehicle_ids(self) -> tuple[int, int]:
        s = self._state
        return (s.system_id or self._target_system or 1, s.component_id or 1)

    def _send_command_long(self, command: int, params: Any, confirmation: int) -> None:
        sysid, compid = self._vehicle_ids()
        self._send(self._enc().command_long_encode(sysid, compid, command, confirmation, *params))

    def _send_setpoint(self, sp: Setpoint) -> None:
        if self._transport is None or not self._state.connected:
            return
        sysid, compid = self._vehicle_ids()
        boot_ms = int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF
        self._send(self._enc().set_position_target_local_ned_encode(
            boot_ms, sysid, compid, **mavlink_fields(sp)))
        with self._lock:
            self._stats["setpoints_sent"] += 1

    def _send_heartbeat(self) -> None:
        self._send(self._enc().heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID,
                                                0, 0, mavlink2.MAV_STATE_ACTIVE))
        with self._lock:
            self._stats["heartbeats_sent"] += 1

    # ----------------------------------------------------------------- threads
    def _tx_loop(self) -> None:
        period = 1.0 / self.setpoint_rate_hz
        next_tick = time.monotonic()
        next_hb = next_tick
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_hb:
                    self._send_heartbeat()
                    next_hb = now + 1.0
                self._check_watchdog(now)
                sp = self._setpoint
                if self._streaming and sp is not None:
                    self._send_setpoint(sp)
            except Exception:  # the stream must survive anything (closed socket, bug)
                log.exception("px4_link stream thread error")
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
                log.exception("px4_link receive error")
                self._stop.wait(0.1)
                continue
            if got is None:
                continue
            data, addr = got
            try:
                msgs = self._parser.feed(data, datagram=t.datagram)
                from_vehicle = False
                for m in msgs:
                    from_vehicle |= self._handle(m)
                if from_vehicle and addr is not None:
                    t.set_peer(addr)  # answer wherever the vehicle speaks from now
            except Exception:
                log.exception("px4_link error handling received data")

    # ----------------------------------------------------------------- receiving
    def _handle(self, m: Any) -> bool:
        """Process one message; True when it came from our vehicle."""
        sysid = m.get_srcSystem()
        mtype = m.get_type()
        if mtype == "HEARTBEAT":
            if m.type in _NON_VEHICLE_TYPES or m.autopilot == MAV_AUTOPILOT_INVALID:
                return False
            if self._target_system is None:
                self._target_system = sysid  # lock onto the first vehicle heard
            if sysid != self._target_system:
                self._count("other_system_messages")
                return False
            if self._state.component_id not in (None, m.get_srcComponent()) and \
                    self._state.connected:
                return True  # another component of the vehicle (camera, ...)
            self._on_heartbeat(m)
            return True
        if self._target_system is None or sysid != self._target_system:
            self._count("other_system_messages")
            return False
        if mtype == "COMMAND_ACK":
            if m.target_system in (0, self.source_system):
                self._commands.handle_ack(m.command, m.result, getattr(m, "progress", 0),
                                          getattr(m, "result_param2", 0))
            return True
        if mtype == "PARAM_VALUE":
            self._on_param_value(m)
            return True
        if mtype == "STATUSTEXT":
            text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
            text = text.rstrip("\x00")
            with self._lock:
                self._last_statustext = (time.monotonic(), text)
            self._emit("statustext", {"severity": m.severity, "text": text})
            return True
        decoder = DECODERS.get(mtype)
        if decoder is not None:
            sample = decoder(m)
            with self._telemetry_cond:
                self._latest[type(sample)] = sample
                self._telemetry_cond.notify_all()
            if isinstance(sample, ExtendedSysState):
                self._on_landed_state(sample.landed_state)
            self._dispatch(sample)
        return True

    def _on_heartbeat(self, m: Any) -> None:
        now = time.monotonic()
        custom = bool(m.base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        mode = decode_custom_mode(m.custom_mode) if custom else "UNKNOWN"
        armed = bool(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        events: list[tuple[str, dict[str, Any]]] = []
        with self._telemetry_cond:
            old = self._state
            self._stats["heartbeats_received"] += 1
            self._state = replace(old, connected=True, system_id=m.get_srcSystem(),
                                  component_id=m.get_srcComponent(), mode=mode,
                                  custom_mode=m.custom_mode, base_mode=m.base_mode, armed=armed,
                                  system_status=m.system_status, autopilot=m.autopilot,
                                  vehicle_type=m.type, last_heartbeat=now,
                                  heartbeats=old.heartbeats + 1)
            if not old.connected:
                if self._ever_connected:
                    self._stats["reconnects"] += 1
                self._ever_connected = True
                events.append(("connected", {"system_id": m.get_srcSystem(),
                                             "component_id": m.get_srcComponent(),
                                             "reconnect": self._stats["reconnects"] > 0}))
            if old.mode != mode and old.heartbeats:
                events.append(("mode_changed", {"old": old.mode, "new": mode}))
                if old.mode == "OFFBOARD" and self._offboard_active and not self._leaving_offboard:
                    self._offboard_active = False
                    events.append(("offboard_lost", {"new_mode": mode}))
            if old.armed != armed and old.heartbeats:
                events.append(("armed_changed", {"armed": armed}))
            self._telemetry_cond.notify_all()
        for name, details in events:
            self._emit(name, details)

    def _on_landed_state(self, landed_state: int) -> None:
        with self._telemetry_cond:
            old = self._state.landed_state
            if old == landed_state:
                return
            self._state = replace(self._state, landed_state=landed_state)
            self._telemetry_cond.notify_all()
        self._emit("landed_changed", {"old": old, "new": landed_state,
                                      "name": self._state.landed_state_name})

    def _on_param_value(self, m: Any) -> None:
        name = m.param_id if isinstance(m.param_id, str) else bytes(m.param_id).decode()
        name = name.rstrip("\x00")
        if m.param_type in (mavlink2.MAV_PARAM_TYPE_REAL32, mavlink2.MAV_PARAM_TYPE_REAL64):
            value: float | int = float(m.param_value)
        else:  # PX4 sends integers bytewise inside the float field
            value = float_bits_to_int(m.param_value)
        with self._telemetry_cond:
            for slot in self._param_waiters.get(name, []):
                if not slot:
                    slot.append(value)
            self._telemetry_cond.notify_all()

    def _check_watchdog(self, now: float) -> None:
        with self._telemetry_cond:
            s = self._state
            if not s.connected or s.last_heartbeat is None:
                return
            silent = now - s.last_heartbeat
            if silent <= self.heartbeat_timeout:
                return
            self._state = replace(s, connected=False)
            self._stats["disconnects"] += 1
            self._telemetry_cond.notify_all()
        self._emit("disconnected", {"system_id": s.system_id, "silent_s": silent})

    def _recent_statustext(self) -> str:
        st = self._last_statustext
        if st is not None and time.monotonic() - st[0] < 1.0:
            return f"vehicle says: {st[1]}"
        return ""

    # ----------------------------------------------------------------- callbacks
    def _count(self, key: str) -> None:
        with self._lock:
            self._stats[key] += 1

    def _dispatch(self, sample: Any) -> None:
        for kind, cb in list(self._listeners):
            if kind is None or isinstance(sample, kind):
                self._safe_call(cb, sample)

    def _emit(self, name: str, details: dict[str, Any]) -> None:
        log.debug("px4_link event %s %s", name, details)
        for cb in list(self._event_listeners):
            self._safe_call(cb, name, details)

    def _safe_call(self, cb: Callable[..., Any], *args: Any) -> None:
        try:
            cb(*args)
        except Exception:
            self._count("callback_errors")
            log.exception("px4_link callback %r raised", cb)

