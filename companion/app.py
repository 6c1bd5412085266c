"""The companion: Zenoh on one side, PX4 over MAVLink on the other.

Setpoints in (``<id>/setpoint``) -> px4_link's offboard stream. PX4 telemetry out:
``<id>/sensor`` (SensorCombined from HIGHRES_IMU), ``<id>/state`` (VehicleState), camera
frames on ``<id>/image``, failsafe events on ``<id>/events``. Commands arrive on the
``<id>/command`` service.

Link-loss failsafe: the setpoint subscription has a deadline. When it is missed while
the companion is flying offboard, it commands PX4 HOLD (AUTO.LOITER) so the drone
holds position in a known mode instead of drifting out of OFFBOARD on stale data, and
publishes a FailsafeEvent. When setpoints return it resumes OFFBOARD only with
``resume_on_setpoints``; otherwise it waits for an explicit ``offboard_start``.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from companion.interface import Command, CommandResult, FailsafeEvent, VehicleState
from px4_link import Px4Link
from px4_link.commands import CommandError
from px4_link.setpoints import PositionSetpoint, SetpointRejected, VelocitySetpoint
from px4_link.telemetry import Attitude, Battery, Imu, LocalPosition
from zenoh_robot import Node
from zenoh_robot.events import SubscriptionEventCallbacks
from zenoh_robot.image_transport import ImagePublisher, encode_strip
from zenoh_robot.msgs import Header, Image, SensorCombined, Setpoint
from zenoh_robot.publisher import PublisherClosed
from zenoh_robot.tools.stream_metrics import StreamRecorder
from zenoh_robot.tools.stream_profiles import StreamProfile, stream_profile

from .camera import RateKeeper, open_source

log = logging.getLogger("companion")


@dataclass
class CompanionConfig:
    drone_id: str = "uav1"
    profile: StreamProfile = field(default_factory=lambda: stream_profile("resilient"))
    setpoint_deadline: float = 1.0
    resume_on_setpoints: bool = False
    sensor_rate_hz: float = 200.0        # the thesis's SensorCombined rate; asked of PX4 via MAVLink
    state_rate_hz: float = 5.0
    camera: str | None = "test"          # None: no images
    camera_rate_hz: float = 30.0
    image_width: int = 320
    image_height: int = 240


class Companion:
    def __init__(self, node: Node, link: Px4Link, config: CompanionConfig) -> None:
        self.node, self.link, self.config = node, link, config
        q = config.profile.qos
        self.setpoints = StreamRecorder()
        self.sent = {name: StreamRecorder() for name in ("sensor", "state", "image")}
        self.setpoints_rejected = 0
        self.failsafe = ""                # why we hold, or ""
        self.offboard_wanted = False      # the operator asked for OFFBOARD and not since for anything else
        self.last_setpoint_at = 0.0
        self.events_sent: list[str] = []
        self._lock = threading.Lock()
        # PX4 commands wait for an ACK (up to seconds): never on the executor's threads.
        self._commands = ThreadPoolExecutor(max_workers=1, thread_name_prefix="px4-cmd")

        self.sensor_pub = node.create_publisher(SensorCombined, "sensor", q["sensor"])
        self.state_pub = node.create_publisher(VehicleState, "state", q["state"])
        self.events_pub = node.create_publisher(FailsafeEvent, "events", q["events"])
        self.image_pub: Any = None
        if config.camera:
            if config.profile.image_mode == "sliced":
                self.image_pub = ImagePublisher(node, "image", q["image"], quality=config.profile.jpeg_quality)
            else:
                self.image_pub = node.create_publisher(Image, "image", q["image"])
        self.setpoint_sub = node.create_subscription(
            Setpoint, "setpoint", self._on_setpoint, q["setpoint"].replace(deadline=config.setpoint_deadline),
            event_callbacks=SubscriptionEventCallbacks(deadline=self._on_deadline_missed))
        node.create_service("command", Command, CommandResult, self._on_command)
        node.create_timer(1.0 / config.state_rate_hz, self._publish_state)
        # The QoS deadline event is the trigger; this watchdog is its backstop, checked at 20 Hz,
        # so the failsafe never depends on one mechanism alone.
        node.create_timer(0.05, self._watchdog)
        link.add_listener(self._on_imu, Imu)
        self._stop = threading.Event()
        self._camera_thread: threading.Thread | None = None
        if config.camera:
            self._camera_thread = threading.Thread(target=self._camera_loop, name="camera", daemon=True)
            self._camera_thread.start()
        node.add_on_close(self.close)

    # -- setpoints -------------------------------------------------------------------
    def _on_setpoint(self, msg: Setpoint, info: Any) -> None:
        self.setpoints.record(info.seq, info.source_stamp_ns, info.received_stamp_ns)
        yaw = msg.yaw if math.isfinite(msg.yaw) else None
        sp = (VelocitySetpoint(msg.x, msg.y, msg.z, yaw) if msg.is_velocity
              else PositionSetpoint(msg.x, msg.y, msg.z, yaw))
        try:
            self.link.set_setpoint(sp)
        except SetpointRejected as exc:
            self.setpoints_rejected += 1
            if self.setpoints_rejected == 1 or self.setpoints_rejected % 100 == 0:
                log.warning("setpoint rejected, never sent to PX4: %s (%d so far)", exc, self.setpoints_rejected)
            return
        # Only setpoints PX4 accepted keep the failsafe away: a stream of garbage is no link.
        self.last_setpoint_at = time.monotonic()
        if self.failsafe and self.config.resume_on_setpoints and self.offboard_wanted:
            self._event("setpoints_resumed", "setpoints back: resuming OFFBOARD", "OFFBOARD")
            self.failsafe = ""
            self._commands.submit(self._try, self.link.start_offboard)

    def _watchdog(self) -> None:
        if self.last_setpoint_at and time.monotonic() - self.last_setpoint_at > self.config.setpoint_deadline:
            self._on_deadline_missed(None)

    def _on_deadline_missed(self, status: Any) -> None:
        with self._lock:   # the event and the watchdog may race on a multi-threaded executor
            if not self.offboard_wanted or self.failsafe:
                return
            self.failsafe = f"no setpoint for {self.config.setpoint_deadline:.1f} s"
        self._event("setpoint_deadline_missed", self.failsafe, "HOLD")
        self._commands.submit(self._hold_for_failsafe)

    def _hold_for_failsafe(self) -> None:
        try:
            self.link.stop_offboard(mode="AUTO.LOITER")   # HOLD first, then stop streaming
        except CommandError as exc:
            log.error("failsafe HOLD failed: %s", exc)
            self._event("failsafe_failed", str(exc), "")

    def _event(self, kind: str, detail: str, action: str) -> None:
        log.warning("%s: %s -> %s", kind, detail, action or "no action")
        self.events_sent.append(kind)
        self.events_pub.publish(FailsafeEvent(Header.now(), kind, detail, action))

    # -- commands --------------------------------------------------------------------
    def _on_command(self, cmd: Command) -> CommandResult:
        handlers = {
            "arm": lambda: self.link.arm(),
            "disarm": lambda: self.link.disarm(force=cmd.force),
            "takeoff": lambda: self.link.takeoff(cmd.value or 5.0),
            "land": lambda: self._leave_offboard("AUTO.LAND"),
            "hold": lambda: self._leave_offboard("AUTO.LOITER"),
            "rtl": lambda: self._leave_offboard("AUTO.RTL"),
            "offboard_start": self._offboard_start,
            "offboard_stop": lambda: self._leave_offboard("AUTO.LOITER"),
            "set_param": lambda: self.link.set_param(cmd.text, cmd.value),
        }
        fn = handlers.get(cmd.name)
        if fn is None:
            return CommandResult(False, f"unknown command {cmd.name!r}; commands: {', '.join(handlers)}",
                                 self.link.state.mode)
        if cmd.name == "takeoff" and not (0.5 <= (cmd.value or 5.0) <= 120):
            return CommandResult(False, f"takeoff altitude {cmd.value} m outside 0.5..120", self.link.state.mode)
        future = self._commands.submit(fn)
        try:
            future.result(timeout=15.0)
        except CommandError as exc:
            return CommandResult(False, str(exc), self.link.state.mode)
        except Exception as exc:   # a bad argument, a link that is down
            return CommandResult(False, f"{type(exc).__name__}: {exc}", self.link.state.mode)
        return CommandResult(True, "done", self.link.state.mode)

    def _offboard_start(self) -> None:
        if time.monotonic() - self.last_setpoint_at > self.config.setpoint_deadline:
            raise RuntimeError("no recent setpoints: stream setpoints before asking for OFFBOARD")
        self.link.start_offboard()
        self.offboard_wanted = True
        self.failsafe = ""

    def _leave_offboard(self, mode: str) -> None:
        """Switch mode, then stop the setpoint stream (stop_offboard does both in that order)."""
        self.offboard_wanted = False
        self.failsafe = ""
        if self.link.streaming:
            self.link.stop_offboard(mode=mode)
        else:
            self.link.set_mode(mode)

    def _try(self, fn: Any) -> None:
        try:
            fn()
        except CommandError as exc:
            log.error("%s", exc)

    # -- telemetry -------------------------------------------------------------------
    def _on_imu(self, imu: Imu) -> None:    # px4_link's thread: publish is thread safe
        msg = SensorCombined(
            Header.now(frame_id="base_link"), imu.timestamp_us, list(imu.gyro_rad), 0, 0,
            list(imu.accelerometer_m_s2), 0, list(imu.magnetometer_ga), imu.baro_alt_meter,
            imu.baro_temp_celcius)
        try:
            self.sensor_pub.publish(msg)
        except PublisherClosed:   # shutting down: the link's thread outlived the node by a moment
            return
        self.sent["sensor"].record(self.sensor_pub.sequence, self.sensor_pub.last_stamp_ns)

    def _publish_state(self) -> None:
        st = self.link.state
        pos = self.link.latest(LocalPosition)
        att = self.link.latest(Attitude)
        batt = self.link.latest(Battery)
        self.state_pub.publish(VehicleState(
            Header.now(), st.mode, st.armed, bool(st.landed), self.link.connected, self.link.streaming,
            [pos.x, pos.y, pos.z] if pos else [math.nan] * 3,
            [pos.vx, pos.vy, pos.vz] if pos else [math.nan] * 3,
            [att.roll, att.pitch, att.yaw] if att else [math.nan] * 3,
            batt.remaining_pct / 100.0 if batt else math.nan, batt.voltage_v if batt else math.nan,
            self.failsafe, self.setpoints_rejected))
        self.sent["state"].record(self.state_pub.sequence, self.state_pub.last_stamp_ns)

    def _camera_loop(self) -> None:
        cfg = self.config
        try:
            source = open_source(cfg.camera or "test", cfg.image_width, cfg.image_height)
        except RuntimeError as exc:
            log.error("camera: %s; no images", exc)
            return
        rate = RateKeeper(cfg.camera_rate_hz)
        try:
            while not self._stop.is_set():
                frame = source.read()
                if frame is None:
                    log.warning("camera: end of stream")
                    return
                self._publish_frame(frame)
                rate.wait()
        finally:
            source.close()

    def _publish_frame(self, frame: Any) -> None:
        head = Header.now(frame_id="camera")
        if isinstance(self.image_pub, ImagePublisher):
            self.image_pub.publish(frame, head)
            self.sent["image"].record(self.image_pub.frames - 1, head.stamp)   # slices carry the frame number
            return
        if self.config.profile.image_mode == "jpeg":
            h, w = frame.shape[:2]
            img = Image(head, h, w, "jpeg", 0, 0, encode_strip(frame, self.config.profile.jpeg_quality))
        else:
            img = Image.from_array(frame, header=head)
        self.image_pub.publish(img)
        self.sent["image"].record(self.image_pub.sequence, self.image_pub.last_stamp_ns)

    def close(self) -> None:
        # Runs before the node's publishers go: the link's thread must stop using them first.
        self.link.remove_listener(self._on_imu)
        self._stop.set()
        if self._camera_thread is not None:
            self._camera_thread.join(timeout=2.0)
        self._commands.shutdown(wait=False, cancel_futures=True)

    def summary(self) -> dict[str, Any]:
        s = self.setpoints.summary().as_dict()
        s["lost_pct"] = self.setpoints.lost_pct()
        return {"setpoints": s, "setpoints_rejected": self.setpoints_rejected, "events": self.events_sent,
                "final_mode": self.link.state.mode,
                "logs": {"sent": {k: v.to_dict() for k, v in self.sent.items()},
                         "received": {"setpoint": self.setpoints.to_dict()}}}
