"""PX4's telemetry onto Zenoh: HIGHRES_IMU -> ``<id>/sensor`` (SensorCombined), and the drone's
state at a steady rate -> ``<id>/state`` (VehicleState); and which streams PX4 is asked for, at
what rate (the sensor rate, the lean stream plan), again after PX4 comes up, with a warning when
PX4 delivers the sensor stream slower than asked.

Threads: ``on_imu`` runs on px4_link's receive thread (publish is thread safe; nothing heavier);
``publish_state`` and ``check_sensor_rate`` on the node's executor; requests to PX4 wait for ACKs
and run on the PX4 worker; ``on_link_event`` on px4_link's thread, never blocking.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

from drone_contract.messages import VehicleState
from px4_link.commands import CommandError, CommandTimeout, NotConnected
from px4_link.telemetry import Attitude, Battery, Imu, LocalPosition, SysStatus
from px4_link.vehicle import VehicleLink
from px4_link.wire import message_id
from zenoh_robot.msgs import Header, SensorCombined
from zenoh_robot.publisher import PublisherClosed
from zenoh_robot.tools.stream_metrics import StreamRecorder

from .config import CompanionConfig
from .events import EventReporter
from .params import PX4_STREAMS
from .px4_worker import Px4Worker

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had

# PX4's streams (issue #18). On an onboard link PX4 sends ~240 messages/s in the simulator (~490
# from real SITL) by default, and packing (simulator) and parsing (px4link-rx) them was most of a
# companion's CPU. px4_streams "lean" asks, when the link comes up, for what the companion and
# px4_link read, at the rate each is needed, and switches off what nothing reads; px4_link asks
# again after a PX4 reconnect or reboot (PX4 forgets). HIGHRES_IMU is asked on its own
# (sensor_rate_hz). The rates, and why:
LEAN_STREAMS_HZ: dict[str, float] = {
    # VehicleState's attitude, sampled at 5 Hz: at 10 Hz it is at most 100 ms old. The reboot
    # watch (px4_link/rates.py BootWatch) needs no particular rate: see JUMP_MS there.
    "ATTITUDE": 10.0,
    # VehicleState's position, and the setpoint offset checks (TargetValidator.check_against_vehicle, px4_link's
    # jump check), which want it fresh within ~100 ms: at 20 Hz it is <= 50 ms old, room for jitter.
    "LOCAL_POSITION_NED": 20.0,
    # Only takeoff reads it (home AMSL = alt - relative_alt, which does not move): 1 Hz.
    "GLOBAL_POSITION_INT": 1.0,
    # Read by nothing: off (interval -1). Those after GPS_RAW_INT are real PX4's only (the
    # simulator ACKs them as PX4 does and sends none of them anyway).
    "VFR_HUD": 0.0, "GPS_RAW_INT": 0.0,
    "ATTITUDE_QUATERNION": 0.0, "ODOMETRY": 0.0, "ALTITUDE": 0.0, "DISTANCE_SENSOR": 0.0,
    "ATTITUDE_TARGET": 0.0, "POSITION_TARGET_LOCAL_NED": 0.0, "POSITION_TARGET_GLOBAL_INT": 0.0,
    "SERVO_OUTPUT_RAW": 0.0,
}
# Not asked, PX4's defaults fit: EXTENDED_SYS_STATE 5 Hz (landed state: VehicleState, forced-disarm
# check), BATTERY_STATUS 0.5 Hz (VehicleState's battery), SYS_STATUS 5 Hz, SYSTEM_TIME / TIMESYNC
# (PX4's own link protocol, 1 / 10 Hz), HEARTBEAT (no stream: PX4 refuses an interval for it).
# With the MAVLink tunnel nothing is cut: QGC draws attitude and position from PX4's default streams.
SUMMARY_STREAMS = ("HIGHRES_IMU", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "VFR_HUD",
                   "GPS_RAW_INT", "SYS_STATUS", "EXTENDED_SYS_STATE", "BATTERY_STATUS")


def ask_streams(link: VehicleLink, plan: dict[str, float]) -> dict[str, str]:
    """Ask PX4 for each stream of ``plan`` at its rate (0: off); returns {stream: why} for those
    not applied. All are remembered first, so px4_link asks for every one again after a PX4
    reconnect or reboot even when this round stopped early."""
    for name, hz in plan.items():
        link.telemetry.intervals.remember(message_id(name), hz)
    refused: dict[str, str] = {}
    names = list(plan)
    for i, name in enumerate(names):
        try:
            link.telemetry.request_message_interval(name, plan[name])
        except (CommandTimeout, NotConnected) as exc:
            # PX4 silent or gone: not 4 s more per stream on the command worker; asked again
            # when it comes back.
            refused.update({n: f"not asked: {exc}" for n in names[i:]})
            break
        except CommandError as exc:   # refused (a PX4 build without that stream): its default stays
            refused[name] = str(exc)
    return refused


SENSOR_STREAM = "HIGHRES_IMU"
RATE_SETTLE_S = 2.0            # the delivered rate is NaN this long after start, a reconnect or a new rate
LOW_RATE_WARN_EVERY_S = 60.0


def streams_in_force(config: CompanionConfig) -> str:
    if config.px4_streams not in PX4_STREAMS:
        raise ValueError(f"px4_streams {config.px4_streams!r}: one of {', '.join(PX4_STREAMS)}")
    if config.mavlink_tunnel and config.px4_streams != "default":
        log.info("px4_streams %s not applied: the MAVLink tunnel's QGC reads PX4's default streams",
                 config.px4_streams)
        return "default"
    return config.px4_streams


class TelemetryBridge:
    def __init__(self, link: VehicleLink, sensor_pub: Any, state_pub: Any, sent_sensor: StreamRecorder,
                 sent_state: StreamRecorder, events: EventReporter, worker: Px4Worker,
                 config: Callable[[], CompanionConfig]) -> None:
        self._link, self._sensor_pub, self._state_pub = link, sensor_pub, state_pub
        self._sent_sensor, self._sent_state = sent_sensor, sent_state
        self._events, self._worker = events, worker
        self._config = config             # live: a `param set` replaces the config
        cfg = config()
        self._rate_since = time.monotonic()
        self.sensor_rate_requested = cfg.sensor_rate_hz
        self.px4_streams = streams_in_force(cfg)
        self.streams_asked = dict(LEAN_STREAMS_HZ) if self.px4_streams == "lean" else {}
        self.streams_refused: dict[str, str] = {}   # stream -> why; bounded by the plan
        self._sensor_low_warned = 0.0

    def start(self) -> None:
        self._link.telemetry.add_listener(self.on_imu, Imu)

    def close(self) -> None:
        """Before the node's publishers go: the link's thread must stop using them first."""
        self._link.telemetry.remove_listener(self.on_imu)

    # -- out -----------------------------------------------------------------------
    def on_imu(self, imu: Imu) -> None:    # px4_link's thread: publish is thread safe
        msg = SensorCombined(
            Header.now(frame_id="base_link"), imu.timestamp_us, list(imu.gyro_rad), 0, 0,
            list(imu.accelerometer_m_s2), 0, list(imu.magnetometer_ga), imu.baro_alt_meter,
            imu.baro_temp_celcius)
        try:
            sent = self._sensor_pub.publish(msg)
        except PublisherClosed:   # shutting down: the link's thread outlived the node by a moment
            return
        self._sent_sensor.record(sent.seq, sent.stamp_ns)

    def publish_state(self, failsafe: str, setpoints_rejected: int, offboard_state: str, controller: str,
                      commands_refused: int, link_refused: int = 0) -> None:
        """The vehicle as PX4 reports it, with what the companion adds (its lifecycle, its refusals)."""
        link = self._link
        st = link.state
        pos = link.telemetry.latest(LocalPosition)
        att = link.telemetry.latest(Attitude)
        batt = link.telemetry.latest(Battery)
        sys_status = link.telemetry.latest(SysStatus)
        sent = self._state_pub.publish(VehicleState(
            Header.now(), st.mode, st.armed, bool(st.landed), link.connected, link.offboard.streaming,
            [pos.x, pos.y, pos.z] if pos else [math.nan] * 3,
            [pos.vx, pos.vy, pos.vz] if pos else [math.nan] * 3,
            [att.roll, att.pitch, att.yaw] if att else [math.nan] * 3,
            batt.remaining_pct / 100.0 if batt else math.nan, batt.voltage_v if batt else math.nan,
            failsafe, setpoints_rejected, offboard_state, controller,
            self.sensor_rate_hz(), self.sensor_rate_requested, commands_refused,
            bool(st.armed or (sys_status is not None and sys_status.armable)), link_refused,
            st.mode_name or "", link.offboard.session_mode))
        self._sent_state.record(sent.seq, sent.stamp_ns)

    # -- what PX4 sends --------------------------------------------------------------
    def request_rates(self) -> None:
        # px4_link remembers the interval and asks again after a PX4 reconnect or reboot.
        self._link.telemetry.request_message_interval(SENSOR_STREAM, self.sensor_rate_requested)

    def request_streams(self) -> None:
        """Ask PX4 for the lean streams (nothing with px4_streams default); a refusal or silence
        is logged once per stream and the stream stays at PX4's rate."""
        if not self.streams_asked:
            return
        refused = ask_streams(self._link, self.streams_asked)
        for name, why in refused.items():
            if name not in self.streams_refused:
                log.warning("PX4 stream %s at %g Hz: %s; PX4's own rate applies", name,
                            self.streams_asked[name], why)
            self.streams_refused[name] = why
        if not refused:
            log.info("PX4 streams asked (%s): %s", self.px4_streams,
                     ", ".join(f"{n} {hz:g} Hz" if hz > 0 else f"{n} off" for n, hz in self.streams_asked.items()))

    def set_sensor_rate(self, hz: float) -> None:
        """A live `param set`: ask PX4 (on the worker: it waits for an ACK)."""
        if hz == self.sensor_rate_requested:
            return
        self.sensor_rate_requested = hz
        self._rate_since = time.monotonic()   # the delivered rate settles again before any warning
        self._worker.submit_guarded("sensor rate", self.request_rates)

    def sensor_rate_hz(self) -> float:
        """HIGHRES_IMU rate PX4 really delivers (NaN for the first window after start or a reconnect)."""
        if time.monotonic() - self._rate_since < RATE_SETTLE_S:
            return math.nan
        return self._link.telemetry.rate_hz(SENSOR_STREAM)

    def check_sensor_rate(self, now: float) -> None:
        rate = self.sensor_rate_hz()
        want = self.sensor_rate_requested
        if math.isnan(rate) or not self._link.connected or rate >= self._config().sensor_rate_tolerance * want:
            return
        if now - self._sensor_low_warned >= LOW_RATE_WARN_EVERY_S:
            self._sensor_low_warned = now
            self._events.event("sensor_rate_low",
                               f"PX4 delivers HIGHRES_IMU at {rate:.0f} Hz, {want:g} Hz requested", "")

    def on_link_event(self, name: str, details: dict[str, Any]) -> None:   # px4_link's thread: never block
        if name == "connected" and not details.get("reconnect"):
            # PX4 came up after the companion: px4_link re-asks only after a *re*connect, so ask now.
            self._rate_since = time.monotonic()
            self._worker.submit_guarded("sensor rate", self.request_rates)
            self._worker.submit_guarded("px4 streams", self.request_streams)
        elif (name == "connected" and details.get("reconnect")) or name == "rebooted":
            self._rate_since = time.monotonic()   # px4_link asks PX4 for the intervals again
            streams = f", {self.px4_streams} streams" if self.streams_asked else ""
            self._events.event("px4_reconnected", f"PX4 {'rebooted' if name == 'rebooted' else 'heartbeats back'}: "
                               f"sensor rate{' and streams' if streams else ''} asked again",
                               f"HIGHRES_IMU {self.sensor_rate_requested:g} Hz{streams}")
        elif name == "disconnected":
            why = details.get("why") or f"no PX4 heartbeat for {details.get('silent_s', 0):.1f} s"
            self._events.event("px4_disconnected", str(why), "PX4 commands refused until it is back")
        elif name == "link_up":
            self._events.event("px4_link_up", f"{details.get('connection', 'PX4')}: bytes from PX4 again, "
                               "waiting for its heartbeat", "")
        elif name == "baud_mismatch":
            self._events.event("px4_baud_mismatch", str(details.get("why", "")), "")

    def summary(self) -> dict[str, Any]:
        return {"in_force": self.px4_streams, "asked_hz": self.streams_asked, "refused": self.streams_refused,
                "delivered_hz": {n: self._link.telemetry.rate_hz(n) for n in SUMMARY_STREAMS}}
