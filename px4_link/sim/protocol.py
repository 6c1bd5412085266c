"""The simulator's MAVLink side: UDP endpoint, message handling, telemetry encoding.

Like PX4 SITL's offboard link, the simulator sends from its own port to a fixed target
(localhost:14540 by default) and locks onto the first address a valid MAVLink message
comes from, replying there afterwards (PX4 initialises its UDP client address once).
"""
from __future__ import annotations

import errno
import math
import socket
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..modes import encode_custom_mode
from ..wire import Encoder, Parser, float_bits_to_int, int_to_float_bits, mavlink2, message_name
from .available_modes import AvailableModes
from .commander import ACCEPTED, DENIED, FAILED, ON_GROUND, Commander, ReceivedSetpoint, int_param
from .params import INT32, ParamStore
from .physics import PointMassQuad

SETPOINT_LOG_CAP = 8192   # setpoints kept in ``setpoint_log`` (400 s at 20 Hz)

# PX4's onboard-link (MAV_x_MODE = Onboard) default stream rates, Hz (mavlink_main.cpp).
DEFAULT_RATES_HZ: dict[str, float] = {
    "HIGHRES_IMU": 50.0,
    "ATTITUDE": 100.0,
    "LOCAL_POSITION_NED": 30.0,
    "GLOBAL_POSITION_INT": 50.0,
    "BATTERY_STATUS": 0.5,
    "SYS_STATUS": 5.0,
    "EXTENDED_SYS_STATE": 5.0,
    "HOME_POSITION": 0.5,
    "VFR_HUD": 10.0,
    "GPS_RAW_INT": 5.0,
    # Every link mode has these two (mavlink_main.cpp). AVAILABLE_MODES' stream sends only
    # AVAILABLE_MODES_MONITOR, and only once the list changed; CURRENT_MODE goes when vehicle_status has a new
    # sample, which commander publishes at >= 2 Hz: the 0.5 Hz schedule decides.
    "AVAILABLE_MODES": 0.3,
    "CURRENT_MODE": 0.5,
}
AVAILABLE_MODES_ID = 435
MAX_RATE_HZ = 400.0  # the loop cannot honour more; PX4 also caps by link bandwidth
# Streams real PX4 also sends on this link (SUMMARY.txt of the SITL trace) that the simulator
# does not build. PX4 accepts MAV_CMD_SET_MESSAGE_INTERVAL for any message it has a stream
# for (mavlink_receiver.cpp set_message_interval: get_stream_name(msgId) found -> ACCEPTED,
# else FAILED), so the simulator ACKs these too and only records the rate asked.
NOT_SIMULATED_STREAMS: frozenset[str] = frozenset({
    "ATTITUDE_QUATERNION", "ODOMETRY", "ALTITUDE", "DISTANCE_SENSOR", "ATTITUDE_TARGET",
    "POSITION_TARGET_LOCAL_NED", "POSITION_TARGET_GLOBAL_INT", "SERVO_OUTPUT_RAW", "TIMESYNC",
    "ESTIMATOR_STATUS", "VIBRATION", "SCALED_PRESSURE", "SYSTEM_TIME", "MISSION_CURRENT",
    "OPEN_DRONE_ID_LOCATION", "OPEN_DRONE_ID_SYSTEM", "PING", "GPS_GLOBAL_ORIGIN",
})
# PX4 sends a stream only when its uORB source has a new sample, at the first sample after
# the interval: a stream is delivered at source_rate / ceil(source_rate / asked). SITL's
# sensor_combined arrives at ~247 Hz, so 200 Hz asked gives ~123 Hz (trace: 123.5 Hz).
SOURCE_RATES_HZ: dict[str, float] = {"HIGHRES_IMU": 247.0, "ATTITUDE": 247.0}

# SYS_STATUS bitmasks PX4 SITL (SIH) reports once its estimator is up (trace, 3.9 s on):
# gyro, accel, mag, baro, GPS, XY position control, RC receiver (enabled, not present),
# logging, battery; health adds attitude stabilisation, motor outputs, AHRS.
SENSORS_PRESENT = 0x0300402F
SENSORS_ENABLED = 0x0301402F
SENSORS_HEALTH = 0x0320C83F
# Before (trace, first 1.8 s: ~2.2 s after boot): nothing present or enabled yet.
BOOT_PRESENT, BOOT_ENABLED, BOOT_HEALTH = 0, 0, 0x0321C83F
# Then until the estimator is ready: no GPS yet, XY position control not healthy.
WARMUP_PRESENT, WARMUP_ENABLED, WARMUP_HEALTH = 0x0300400F, 0x0301400F, 0x0320883F
PREARM_CHECK = 0x10000000   # MAV_SYS_STATUS_PREARM_CHECK: healthy = the vehicle can arm

MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_MANUAL_INPUT_ENABLED = 64
MAV_MODE_FLAG_STABILIZE_ENABLED = 16
MAV_MODE_FLAG_GUIDED_ENABLED = 8
MAV_MODE_FLAG_AUTO_ENABLED = 4
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
_AUTO_FLAGS = MAV_MODE_FLAG_AUTO_ENABLED | MAV_MODE_FLAG_STABILIZE_ENABLED | MAV_MODE_FLAG_GUIDED_ENABLED

# MAV_PROTOCOL_CAPABILITY bits PX4 reports: MISSION_FLOAT|PARAM_FLOAT|MISSION_INT|COMMAND_INT|
# PARAM_ENCODE_BYTEWISE|SET_POSITION_TARGET_LOCAL_NED|... |MAVLINK2
CAPABILITIES = 1 | 2 | 4 | 8 | 16 | 32 | 64 | 128 | 256 | 1024 | 8192


def base_mode_for(mode: str, armed: bool) -> int:
    """HEARTBEAT base_mode flags PX4 sets for a nav state (mavlink_messages.cpp)."""
    flags = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    if mode in ("MANUAL", "ACRO", "RATTITUDE", "STABILIZED", "ALTCTL"):
        flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | MAV_MODE_FLAG_STABILIZE_ENABLED
    elif mode.startswith("POSCTL"):
        flags |= (MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | MAV_MODE_FLAG_STABILIZE_ENABLED
                  | MAV_MODE_FLAG_GUIDED_ENABLED)
    elif mode.startswith("AUTO") or mode == "OFFBOARD":
        flags |= _AUTO_FLAGS
    return flags


class StreamTable:
    """Per-message send intervals, changeable with MAV_CMD_SET_MESSAGE_INTERVAL."""

    def __init__(self, rates: dict[str, float] | None = None) -> None:
        self.defaults = dict(DEFAULT_RATES_HZ)
        self.rates: dict[str, float] = dict(self.defaults)
        # Intervals (us, as asked: -1 off, 0 default) of streams PX4 has but the simulator
        # never sends; bounded by NOT_SIMULATED_STREAMS.
        self.not_simulated_us: dict[str, float] = {}
        self._next: dict[str, float] = {}
        for name, hz in (rates or {}).items():
            self.set_rate(name, hz)

    def set_rate(self, name: str, hz: float) -> None:
        name = name.upper()
        if name not in self.defaults:
            raise KeyError(name)
        self.rates[name] = min(max(hz, 0.0), MAX_RATE_HZ)
        self._next.pop(name, None)

    def set_interval(self, msg_id: int, interval_us: float) -> bool:
        """PX4 semantics: -1 disables, 0 restores the default, > 0 sets the interval;
        False (PX4: MAV_RESULT_FAILED) for HEARTBEAT and messages PX4 has no stream for."""
        name = message_name(msg_id)
        if name in NOT_SIMULATED_STREAMS:
            self.not_simulated_us[name] = interval_us
            return True
        if name not in self.defaults:
            return False
        if interval_us < 0:
            hz = 0.0
        elif interval_us == 0:
            hz = self.defaults[name]
        else:
            hz = 1e6 / interval_us
        self.set_rate(name, hz)
        return True

    def delivered_hz(self, name: str) -> float:
        """The rate PX4 actually sends ``name`` at, given its source's sample rate."""
        hz = self.rates.get(name.upper(), 0.0)
        source = SOURCE_RATES_HZ.get(name.upper())
        if hz <= 0 or source is None or hz >= source:
            return min(hz, source) if source is not None else hz
        return source / math.ceil(source / hz - 1e-9)

    def due(self, now: float) -> list[str]:
        out = []
        for name in self.rates:
            hz = self.delivered_hz(name)
            if hz <= 0:
                continue
            nxt = self._next.get(name)
            if nxt is None or now >= nxt:
                out.append(name)
                period = 1.0 / hz
                # Advance on schedule, but never try to catch up a backlog in a burst.
                self._next[name] = now + period if nxt is None or now - nxt > period else nxt + period
        return out

    def next_due(self) -> float:
        return min(self._next.values(), default=0.0)


@dataclass
class EndpointStats:
    bytes_received: int = 0
    messages_received: int = 0
    bad_frames: int = 0
    messages_sent: int = 0
    sent_by_type: dict[str, int] = field(default_factory=dict)
    commands: list[tuple[float, int, int]] = field(default_factory=list)  # (t, command, result)


class SimProtocol:
    """Decodes what the companion sends and encodes what PX4 would send back."""

    def __init__(self, sock: socket.socket, target: tuple[str, int], sysid: int, compid: int,
                 commander: Commander, vehicle: PointMassQuad, params: ParamStore,
                 streams: StreamTable, home: tuple[float, float, float], boot_time: float,
                 on_log: Callable[[str], None] | None = None,
                 on_internal_error: Callable[[str], None] | None = None,
                 modes: AvailableModes | None = None) -> None:
        self.sock = sock
        self.dest = target
        self._locked = False
        self.sysid, self.compid = sysid, compid
        self.commander, self.vehicle, self.params, self.streams = commander, vehicle, params, streams
        self.home = home
        self.boot_time = boot_time
        self.modes = modes if modes is not None else AvailableModes()
        self.stats = EndpointStats()
        self._parser = Parser()
        self.enc = Encoder(self._write, sysid, compid)
        self._on_log = on_log or (lambda s: None)
        self._on_internal_error = on_internal_error or self._on_log
        self._last_msg_type = ""
        # (MAV_TYPE, source system, time) of every HEARTBEAT heard: the failsafe's GCS link check
        self.on_heartbeat: Callable[[int, int, float], None] | None = None
        # (monotonic receive time, position or None) of every setpoint used: what a latency run matches
        self.setpoint_log: deque[tuple[float, tuple[float, float, float] | None]] = deque(maxlen=SETPOINT_LOG_CAP)

    # ---------------------------------------------------------------- io
    def _write(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.dest)
        except OSError:
            return  # nobody listening (ECONNREFUSED) is normal before the companion starts
        self.stats.messages_sent += 1

    def send(self, msg: Any) -> None:
        self.enc.send(msg)
        t = msg.get_type()
        self.stats.sent_by_type[t] = self.stats.sent_by_type.get(t, 0) + 1

    def drain(self, now: float, max_datagrams: int = 200) -> None:
        """Read every pending datagram without blocking."""
        for _ in range(max_datagrams):
            try:
                data, addr = self.sock.recvfrom(65535)
            except OSError as e:
                if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                    return
                return
            self.stats.bytes_received += len(data)
            msgs = self._parser.feed(data, datagram=True)
            self.stats.bad_frames = self._parser.bad_frames
            if msgs and not self._locked:
                self.dest = addr
                self._locked = True
            for m in msgs:
                self.stats.messages_received += 1
                try:
                    self._handle(m, now)
                except Exception:   # a simulator bug: recorded so the test that caused it fails
                    self._on_internal_error(f"handling {m.get_type()}: {traceback.format_exc()}")

    def boot_ms(self, now: float) -> int:
        return int((now - self.boot_time) * 1000) & 0xFFFFFFFF

    # ---------------------------------------------------------------- incoming
    def _for_us(self, target_system: int, target_component: int) -> bool:
        return target_system in (0, self.sysid) and target_component in (0, self.compid)

    def _handle(self, m: Any, now: float) -> None:
        t = m.get_type()
        if t == "SET_POSITION_TARGET_LOCAL_NED":
            if self._for_us(m.target_system, m.target_component):
                self._on_setpoint(m, now)
        elif t == "COMMAND_LONG":
            if self._for_us(m.target_system, m.target_component):
                self._on_command(m, now)
        elif t == "PARAM_REQUEST_LIST":
            if self._for_us(m.target_system, m.target_component):
                names = self.params.names()
                for i, name in enumerate(names):
                    self._send_param(name, i, len(names))
        elif t == "PARAM_REQUEST_READ":
            if self._for_us(m.target_system, m.target_component):
                names = self.params.names()
                name = _text(m.param_id)
                if m.param_index >= 0 and m.param_index < len(names):
                    name = names[m.param_index]
                if name in self.params:
                    self._send_param(name, names.index(name), len(names))
        elif t == "PARAM_SET":
            if self._for_us(m.target_system, m.target_component):
                self._on_param_set(m)
        elif t == "COMMAND_ACK":
            if m.target_system in (0, self.sysid):
                self.commander.on_command_ack(m.command)
        elif t == "HEARTBEAT":
            if self.on_heartbeat is not None:
                self.on_heartbeat(m.type, m.get_srcSystem(), now)
        elif t == "TIMESYNC" and m.tc1 == 0:
            self.send(self.enc.timesync_encode(int(time.monotonic() * 1e9), m.ts1))

    def _on_setpoint(self, m: Any, now: float) -> None:
        if m.coordinate_frame != mavlink2.MAV_FRAME_LOCAL_NED:
            self._on_log(f"ignored setpoint in frame {m.coordinate_frame}")
            return
        mask = m.type_mask
        pos = None if mask & 0x7 == 0x7 else (m.x, m.y, m.z)
        vel = None if mask & 0x38 == 0x38 else (m.vx, m.vy, m.vz)
        yaw = None if mask & 0x400 else m.yaw
        used = [v for v in (pos or ()) + (vel or ())] + ([] if yaw is None else [yaw])
        if (pos is None and vel is None) or not all(math.isfinite(v) for v in used):
            self._on_log("ignored setpoint with nothing usable")
            return
        self.commander.on_setpoint(ReceivedSetpoint(now, mask, m.coordinate_frame, pos, vel, yaw,
                                                    m.get_srcSystem()))
        self.setpoint_log.append((time.monotonic(), pos))

    def _on_command(self, m: Any, now: float) -> None:
        try:
            self._run_command(m, now)
        except Exception:
            # A simulator bug, never an answer: a FAILED ACK would pass for a refusal in a test
            # that expects one. No ACK; recorded as an internal error (tests/conftest.py fails on it).
            self._on_internal_error(f"command {m.command}: {traceback.format_exc()}")

    def _run_command(self, m: Any, now: float) -> None:
        p = [m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7]
        cmd = m.command
        if cmd == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            wanted_id = int_param(p[0], -1)
            # PX4 refuses what it cannot do: a response target (param7) or param3/param4 in use.
            extras_unused = all(int_param(v) == 0 for v in (p[2], p[3], p[6]))
            ok = math.isfinite(p[1]) and extras_unused and self.streams.set_interval(wanted_id, p[1])
            result, text = (ACCEPTED, None) if ok else (FAILED, f"stream {wanted_id} not available")
        elif cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE and int_param(p[0], -1) == AVAILABLE_MODES_ID:
            self._request_available_modes(m, p, now)
            return
        elif cmd in (mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            wanted = 148 if cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES else int_param(p[0], -1)
            msg = self.build(wanted, now)
            result, text = (ACCEPTED, None) if msg is not None else (FAILED, None)
            if msg is not None:
                self._ack(m, cmd, result)
                self.send(msg)
                self.stats.commands.append((now, cmd, result))
                return
        else:
            r = self.commander.handle_command(cmd, p, now)
            result, text = r.result, r.text
            self.flush_statustexts()   # what the commander printed on the way comes first, as in PX4
        if text:
            sev = mavlink2.MAV_SEVERITY_INFO if result == ACCEPTED else mavlink2.MAV_SEVERITY_CRITICAL
            self.statustext(sev, text)
        self._ack(m, cmd, result)
        if cmd == mavlink2.MAV_CMD_DO_SET_MODE:
            # Commander and the mode manager both answer DO_SET_MODE: two ACKs, 0-9 ms apart.
            self._ack(m, cmd, result)
        self.stats.commands.append((now, cmd, result))

    def _request_available_modes(self, m: Any, p: list[float], now: float) -> None:
        """MavlinkReceiver::handle_request_message_command -> MavlinkStreamAvailableModes::request_message: the
        modes go out from inside the request (param2: 0 all, else the 1-based index), the ACK after them
        (ACCEPTED, or DENIED for an index past the list). PX4 paces the modes by the link's data rate, which on
        UDP (MAV_x_RATE 4 MB/s in SITL) is under its 1 ms threshold: back to back, as here."""
        entries = self.modes.requested(int_param(p[1]))
        total = len(self.modes.entries())
        for i, e in enumerate(entries or ()):
            index = int_param(p[1]) or i + 1
            self.send(self.enc.available_modes_encode(total, index, e.standard_mode, e.custom_mode,
                                                      e.properties, e.mode_name.encode()))
        result = ACCEPTED if entries is not None else DENIED
        self._ack(m, m.command, result)
        self.stats.commands.append((now, m.command, result))

    def _ack(self, m: Any, cmd: int, result: int) -> None:
        self.send(self.enc.command_ack_encode(cmd, result, 0, 0, m.get_srcSystem(),
                                              m.get_srcComponent()))

    def _on_param_set(self, m: Any) -> None:
        name = _text(m.param_id)
        if name not in self.params or name == "MAV_SYS_ID":
            self.statustext(mavlink2.MAV_SEVERITY_ERROR, f"param {name} not settable")
            return
        if self.params.type_of(name) == INT32:
            value: float | int = (float_bits_to_int(m.param_value)
                                  if m.param_type != mavlink2.MAV_PARAM_TYPE_REAL32
                                  else int(round(m.param_value)))
        else:
            value = float(m.param_value)
        self.params.set(name, value)
        names = self.params.names()
        self._send_param(name, names.index(name), len(names))

    def _send_param(self, name: str, index: int, count: int) -> None:
        value = self.params[name]
        if self.params.type_of(name) == INT32:
            wire, ptype = int_to_float_bits(int(value)), mavlink2.MAV_PARAM_TYPE_INT32
        else:
            wire, ptype = float(value), mavlink2.MAV_PARAM_TYPE_REAL32
        self.send(self.enc.param_value_encode(name.encode(), wire, ptype, count, index))

    def flush_statustexts(self) -> None:
        """Send what the commander printed (caller holds the simulator's lock)."""
        for sev, text in self.commander.statustexts:
            self.statustext(sev, text)
        self.commander.statustexts.clear()

    def statustext(self, severity: int, text: str) -> None:
        self.send(self.enc.statustext_encode(severity, text.encode()[:50]))

    # ---------------------------------------------------------------- outgoing
    def heartbeat(self) -> None:
        c = self.commander
        status = (mavlink2.MAV_STATE_CRITICAL if c.failsafe else
                  mavlink2.MAV_STATE_ACTIVE if c.armed else mavlink2.MAV_STATE_STANDBY)
        if c.mode == "TERMINATION":
            status = mavlink2.MAV_STATE_FLIGHT_TERMINATION
        self.send(self.enc.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4,
                                            base_mode_for(c.mode, c.armed),
                                            encode_custom_mode(c.mode), status))

    def send_commands(self) -> None:
        """COMMAND_LONGs PX4 itself originates (gimbal manager on LAND)."""
        for c in self.commander.take_outgoing():
            self.send(self.enc.command_long_encode(self.sysid, c.target_component, c.command,
                                                   c.confirmation, *c.params))

    def send_streams(self, now: float) -> None:
        for name in self.streams.due(now):
            msg = self.build(name, now)
            if msg is not None:
                self.send(msg)

    def build(self, what: str | int, now: float) -> Any:
        """Encode one message from the current state (by name or id); None if unknown."""
        name: str
        if isinstance(what, int):
            found = message_name(what)
            if found is None:
                return None
            name = found
        else:
            name = what
        fn = getattr(self, f"_build_{name.lower()}", None)
        return fn(now) if fn is not None else None

    def _latlon(self) -> tuple[float, float, float]:
        lat0, lon0, alt0 = self.home
        n, e, d = self.vehicle.pos
        lat = lat0 + math.degrees(n / 6378137.0)
        lon = lon0 + math.degrees(e / (6378137.0 * math.cos(math.radians(lat0))))
        return lat, lon, alt0 - d

    def _build_highres_imu(self, now: float) -> Any:
        s = self.vehicle.imu(self.home[2])
        return self.enc.highres_imu_encode(
            int((now - self.boot_time) * 1e6), *map(float, s.accel), *map(float, s.gyro),
            *map(float, s.mag), s.pressure_hpa, 0.0, s.baro_alt, s.temperature_c, 0x1FFF, 0)

    def _build_attitude(self, now: float) -> Any:
        v = self.vehicle
        return self.enc.attitude_encode(self.boot_ms(now), v.roll, v.pitch, v.yaw,
                                        *map(float, v.rates))

    def _build_local_position_ned(self, now: float) -> Any:
        v = self.vehicle
        return self.enc.local_position_ned_encode(self.boot_ms(now), *map(float, v.pos),
                                                  *map(float, v.vel))

    def _build_global_position_int(self, now: float) -> Any:
        v = self.vehicle
        lat, lon, alt = self._latlon()
        hdg = int(math.degrees(v.yaw) % 360 * 100)
        return self.enc.global_position_int_encode(
            self.boot_ms(now), int(lat * 1e7), int(lon * 1e7), int(alt * 1000),
            int(-v.pos[2] * 1000), int(v.vel[0] * 100), int(v.vel[1] * 100),
            int(v.vel[2] * 100), hdg)

    def _battery(self, now: float) -> tuple[float, float, int]:
        remaining = self.vehicle.battery.percent   # physics.Battery: the failsafe reads the same pack
        current = 12.0 if self.commander.armed else 0.5
        return 16.8 - 0.02 * (100 - remaining), current, remaining

    def _build_battery_status(self, now: float) -> Any:
        volts, amps, remaining = self._battery(now)
        cells = [int(volts * 1000 / 4)] * 4 + [65535] * 6
        return self.enc.battery_status_encode(0, mavlink2.MAV_BATTERY_FUNCTION_ALL,
                                              mavlink2.MAV_BATTERY_TYPE_LIPO, 2500, cells,
                                              int(amps * 100), -1, -1, remaining)

    def _build_sys_status(self, now: float) -> Any:
        volts, amps, remaining = self._battery(now)
        c = self.commander
        if not c.sensors_up():
            present, enabled, health = BOOT_PRESENT, BOOT_ENABLED, BOOT_HEALTH
        elif not c.estimate_valid():
            present, enabled, health = WARMUP_PRESENT, WARMUP_ENABLED, WARMUP_HEALTH
        else:
            present, enabled, health = SENSORS_PRESENT, SENSORS_ENABLED, SENSORS_HEALTH
        # Real PX4 sets PREARM_CHECK only in health; MAVSDK and QGC-alikes read it from
        # present/enabled first, so once sensors are up it is set there too, and in health
        # while the vehicle can arm.
        if c.sensors_up():
            present, enabled = present | PREARM_CHECK, enabled | PREARM_CHECK
        if c.armable():
            health |= PREARM_CHECK
        return self.enc.sys_status_encode(present, enabled, health, 150,
                                          int(volts * 1000),
                                          int(amps * 100), remaining, 0, 0, 0, 0, 0, 0)

    def _build_extended_sys_state(self, now: float) -> Any:
        return self.enc.extended_sys_state_encode(mavlink2.MAV_VTOL_STATE_UNDEFINED,
                                                  self.commander.landed_state)

    def _build_home_position(self, now: float) -> Any:
        lat, lon, alt = self.home
        return self.enc.home_position_encode(int(lat * 1e7), int(lon * 1e7), int(alt * 1000),
                                             0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    def _build_vfr_hud(self, now: float) -> Any:
        v = self.vehicle
        speed = math.hypot(v.vel[0], v.vel[1])
        _, _, alt = self._latlon()
        throttle = 0 if not self.commander.armed else 50
        return self.enc.vfr_hud_encode(speed, speed, int(math.degrees(v.yaw) % 360), throttle,
                                       alt, -float(v.vel[2]))

    def _build_gps_raw_int(self, now: float) -> Any:
        lat, lon, alt = self._latlon()
        v = self.vehicle
        return self.enc.gps_raw_int_encode(int((now - self.boot_time) * 1e6), 3, int(lat * 1e7),
                                           int(lon * 1e7), int(alt * 1000), 70, 100,
                                           int(math.hypot(v.vel[0], v.vel[1]) * 100), 65535, 12)

    def _build_available_modes(self, now: float) -> Any:
        """The AVAILABLE_MODES stream's own message: AVAILABLE_MODES_MONITOR, once the list changed."""
        return self.enc.available_modes_monitor_encode(self.modes.seq) if self.modes.changed else None

    def _build_current_mode(self, now: float) -> Any:
        """CURRENT_MODE.hpp: the displayed mode, the user's intention (a failsafe's mode is not one)."""
        c = self.commander
        intended = c.user_mode if c.failsafe else c.mode
        entry = self.modes.entry_for(c.mode)
        return self.enc.current_mode_encode(entry.standard_mode if entry is not None else 0,
                                            encode_custom_mode(c.mode), encode_custom_mode(intended))

    def _build_autopilot_version(self, now: float) -> Any:
        # flight_sw_version 1.15.0 (FIRMWARE_VERSION_TYPE_OFFICIAL = 255)
        return self.enc.autopilot_version_encode(CAPABILITIES, (1 << 24) | (15 << 16) | 255,
                                                 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
                                                 self.sysid)

    @property
    def landed(self) -> bool:
        return self.commander.landed_state == ON_GROUND


def _text(v: Any) -> str:
    s = v if isinstance(v, str) else bytes(v).decode(errors="replace")
    return s.rstrip("\x00")
