"""The GCS node: streams setpoints to each drone, listens to its telemetry, images and events.

One ``Gcs`` holds one Node (one Zenoh session) and a ``DroneLink`` per drone. Drones
are given (``--drones uav1,uav2``) or discovered from the ``*/state`` topics they
publish. Everything a dashboard or a summary shows is read from ``DroneLink``.
"""
from __future__ import annotations

import logging
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.interface import Command, CommandResult, FailsafeEvent, VehicleState
from zenoh_robot import Node
from zenoh_robot.image_transport import FrameInfo, ImageSubscription
from zenoh_robot.msgs import Header, Image, SensorCombined, Setpoint
from zenoh_robot.services import ServiceCallError
from zenoh_robot.tools.stream_metrics import StreamRecorder
from zenoh_robot.tools.stream_profiles import StreamProfile, stream_profile

from .patterns import make_pattern, path_distance

log = logging.getLogger("gcs")
_DRONE_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass
class GcsConfig:
    drones: list[str] = field(default_factory=list)     # empty: discover
    pattern: str = "thesis"
    rate_hz: float = 10.0
    altitude: float = 5.0
    size: float = 10.0
    speed: float = 2.0
    profile: StreamProfile = field(default_factory=lambda: stream_profile("resilient"))
    save_image: Path | None = None   # write the latest frame here every `save_every` s
    save_every: float = 5.0


@dataclass
class ImageStats:
    frames: int = 0
    complete: int = 0
    last_age_ms: float = float("nan")
    ages: list[float] = field(default_factory=list)


class DroneLink:
    """Everything the GCS sends to and knows about one drone."""

    def __init__(self, gcs: "Gcs", drone_id: str) -> None:
        self.id = drone_id
        self.gcs = gcs
        node, cfg = gcs.node, gcs.config
        q = cfg.profile.qos
        self.setpoints_sent = 0
        self.state: VehicleState | None = None
        self.state_at = 0.0
        self.events: list[FailsafeEvent] = []
        self.streams = {name: StreamRecorder() for name in ("sensor", "state", "image")}
        self.sent = {"setpoint": StreamRecorder()}
        self.image = ImageStats()
        self.latest_frame: np.ndarray | None = None
        self.max_path_error = 0.0
        ns = f"/{drone_id}"
        self.setpoint_pub = node.create_publisher(Setpoint, f"{ns}/setpoint", q["setpoint"])
        node.create_subscription(SensorCombined, f"{ns}/sensor", self._on_sensor, q["sensor"])
        node.create_subscription(VehicleState, f"{ns}/state", self._on_state, q["state"])
        node.create_subscription(FailsafeEvent, f"{ns}/events", self._on_event, q["events"])
        if cfg.profile.image_mode == "sliced":
            ImageSubscription(node, f"{ns}/image", self._on_frame, q["image"])
        else:   # raw rgb8 or one JPEG per Image message
            node.create_subscription(Image, f"{ns}/image", self._on_raw_image, q["image"])
        self.commands = node.create_client(f"{ns}/command", Command, CommandResult)

    # -- telemetry -------------------------------------------------------------------
    def _on_sensor(self, msg: SensorCombined, info: Any) -> None:
        self.streams["sensor"].record(info.seq, info.source_stamp_ns, info.received_stamp_ns)

    def _on_state(self, msg: VehicleState, info: Any) -> None:
        self.streams["state"].record(info.seq, info.source_stamp_ns, info.received_stamp_ns)
        self.state, self.state_at = msg, time.monotonic()
        if msg.mode == "OFFBOARD" and self.gcs.flying_pattern:
            x, y = msg.position[0], msg.position[1]
            self.max_path_error = max(self.max_path_error,
                                      path_distance(x, y, self.gcs.config.pattern, self.gcs.config.size))

    def _on_event(self, msg: FailsafeEvent) -> None:
        self.events.append(msg)
        del self.events[:-20]   # bounded
        log.warning("%s: %s (%s) -> %s", self.id, msg.kind, msg.detail, msg.action or "no action")

    def _on_frame(self, img: Image, info: FrameInfo) -> None:
        self.streams["image"].record(info.frame, img.header.stamp)
        self._frame(img.to_array(), info.age_ms, info.complete)

    def _on_raw_image(self, img: Image, info: Any) -> None:
        self.streams["image"].record(info.seq, info.source_stamp_ns, info.received_stamp_ns)
        self._frame(img.to_array(), info.age_ms, True)

    def _frame(self, arr: np.ndarray, age_ms: float, complete: bool) -> None:
        self.image.frames += 1
        self.image.complete += complete
        self.image.last_age_ms = age_ms
        self.latest_frame = arr

    # -- commands --------------------------------------------------------------------
    def command(self, name: str, value: float = 0.0, text: str = "", force: bool = False,
                timeout: float = 8.0) -> CommandResult:
        """Send a command and wait for the drone's answer; errors come back as a failed result."""
        try:
            return self.commands.call(Command(name, float(value), text, force), timeout=timeout)
        except ServiceCallError as exc:
            return CommandResult(False, f"{type(exc).__name__}: {exc}", "")

    def send_setpoint(self, x: float, y: float, z: float, yaw: float) -> None:
        pub = self.setpoint_pub
        pub.publish(Setpoint(Header.now(seq=self.setpoints_sent), x, y, z, yaw, False))
        self.sent["setpoint"].record(pub.sequence, pub.last_stamp_ns)
        self.setpoints_sent += 1

    @property
    def link_age(self) -> float:
        return time.monotonic() - self.state_at if self.state_at else float("inf")


class Gcs:
    def __init__(self, node: Node, config: GcsConfig) -> None:
        self.node = node
        self.config = config
        self.drones: dict[str, DroneLink] = {}
        self._lock = threading.Lock()
        self._pattern = make_pattern(config.pattern, config.altitude, config.size, config.speed)
        self._t0 = time.monotonic()
        self.flying_pattern = False
        self._frozen: tuple[float, float, float, float] | None = None
        self.streaming = True
        for d in config.drones:
            self.add_drone(d)
        if not config.drones:
            # Discovery: any namespace publishing a VehicleState on <id>/state is a drone.
            self._discovery = node.session.declare_subscriber("*/state", self._on_any_state)
        node.create_timer(1.0 / config.rate_hz, self._stream)
        if config.save_image:
            node.create_timer(config.save_every, self._save_images)

    def _on_any_state(self, sample: Any) -> None:   # Zenoh thread: hand over to the executor
        drone_id = str(sample.key_expr).split("/")[0]
        if drone_id not in self.drones and _DRONE_ID.match(drone_id):
            self.node.executor.call_soon(lambda: self.add_drone(drone_id))

    def add_drone(self, drone_id: str) -> DroneLink:
        with self._lock:
            if drone_id not in self.drones:
                log.info("drone %s joined", drone_id)
                self.drones[drone_id] = DroneLink(self, drone_id)
            return self.drones[drone_id]

    def restart_pattern(self, flying: bool = True) -> None:
        self._t0 = time.monotonic()
        self.flying_pattern = flying
        self._frozen = None

    def freeze(self) -> None:
        """Keep sending the current target: a jump back to the start would be refused as too fast."""
        self._frozen = self.target()
        self.flying_pattern = False

    def target(self) -> tuple[float, float, float, float]:
        if self._frozen is not None:
            return self._frozen
        if not self.flying_pattern:
            return 0.0, 0.0, -abs(self.config.altitude), 0.0
        t = self._pattern(time.monotonic() - self._t0)
        return t.x, t.y, t.z, t.yaw

    def _stream(self) -> None:
        if not self.streaming:
            return
        x, y, z, yaw = self.target()
        for drone in list(self.drones.values()):
            drone.send_setpoint(x, y, z, yaw)

    def _save_images(self) -> None:
        from PIL import Image as PILImage
        assert self.config.save_image is not None
        for drone in list(self.drones.values()):
            if drone.latest_frame is not None:
                path = self.config.save_image
                if len(self.drones) > 1:
                    path = path.with_name(f"{path.stem}_{drone.id}{path.suffix}")
                PILImage.fromarray(drone.latest_frame).save(path)
