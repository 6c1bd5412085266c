"""The GCS node: streams setpoints to each drone, listens to its telemetry, images and events.

One ``Gcs`` holds one Node (one Zenoh session) and a ``DroneLink`` per drone. Drones
are given (``--drones uav1,uav2``) or discovered from the ``*/state`` topics they
publish. Everything a dashboard or a summary shows is read from ``DroneLink``.

Identity: every setpoint and command carries this GCS's ``client_id`` (``user@host`` by
default), and the session declares the liveliness token ``zr_gcs/<client_id>`` by which
a drone's companion knows its controller is still there (companion/control.py).

Targets start where the drone is: until the drone's offboard session is active under this
GCS, the target follows the drone's reported position (climbing towards the altitude at
most ``MAX_LEAD_M`` ahead); once active, the pattern is flown relative to that anchor. So
a restarted GCS, or a resume after a failsafe hold anywhere, never asks for a jump. Each
drone has its own anchor, so no two drones are sent the same point.
"""
from __future__ import annotations

import logging
import math
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.interface import (
    CONTROL_TOKEN_PREFIX,
    FAILSAFE_KINDS,
    Command,
    CommandResult,
    DroneSetpoint,
    FailsafeEvent,
    VehicleState,
)
from zenoh_robot import Node
from zenoh_robot.image_transport import FrameInfo, ImageSubscription
from zenoh_robot.msgs import Header, Image, SensorCombined
from zenoh_robot.services import ServiceCallError
from zenoh_robot.tools.stream_metrics import StreamRecorder
from zenoh_robot.tools.stream_profiles import StreamProfile, stream_profile

from .patterns import Target, make_pattern, path_distance

log = logging.getLogger("gcs")
_DRONE_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
MAX_LEAD_M = 5.0     # how far ahead of the drone a target may lie (the companion refuses > 10 m)


def default_client_id() -> str:
    import getpass
    import socket
    raw = f"{getpass.getuser()}@{socket.gethostname()}"
    return re.sub(r"[^A-Za-z0-9_.@:+-]", "_", raw)[:64]


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
    client_id: str = field(default_factory=default_client_id)
    take_control: bool = False       # take control from another GCS at start (explicit takeover)
    auto_fly: bool = True            # fly the pattern as soon as a drone's session is active (no --mission)


@dataclass
class ImageStats:
    frames: int = 0
    complete: int = 0
    last_age_ms: float = float("nan")
    ages: list[float] = field(default_factory=list)


class DroneLink:
    """Everything the GCS sends to and knows about one drone."""

    MAX_EVENTS = 20

    def __init__(self, gcs: Gcs, drone_id: str) -> None:
        self.id = drone_id
        self.gcs = gcs
        node, cfg = gcs.node, gcs.config
        q = cfg.profile.qos
        self.setpoints_sent = 0
        self.state: VehicleState | None = None
        self.state_at = 0.0
        self.events: list[FailsafeEvent] = []
        self.failures: list[str] = []     # failsafes and refusals addressed to this GCS (bounded)
        self.events_seen = 0
        self.streams = {name: StreamRecorder() for name in ("sensor", "state", "image")}
        self.sent = {"setpoint": StreamRecorder()}
        self.image = ImageStats()
        self.latest_frame: np.ndarray | None = None
        self.max_path_error = 0.0
        # Targets: see the module docstring.
        self.fly = gcs.config.auto_fly          # fly the pattern once the session is active
        self._hover: Target | None = None
        self._anchor: Target | None = None
        self._t0 = 0.0
        self._frozen: Target | None = None
        ns = f"/{drone_id}"
        self.setpoint_pub = node.create_publisher(DroneSetpoint, f"{ns}/setpoint", q["setpoint"])
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
        if msg.mode == "OFFBOARD" and self._anchor is not None:
            x, y = msg.position[0] - self._anchor.x, msg.position[1] - self._anchor.y
            self.max_path_error = max(self.max_path_error,
                                      path_distance(x, y, self.gcs.config.pattern, self.gcs.config.size))

    @property
    def in_control(self) -> bool:
        return self.state is not None and self.state.controller == self.gcs.config.client_id

    @property
    def session_active(self) -> bool:
        s = self.state
        return s is not None and s.offboard_state == "active" and self.in_control

    def _on_event(self, msg: FailsafeEvent) -> None:
        self.events.append(msg)
        del self.events[:-self.MAX_EVENTS]   # bounded
        self.events_seen += 1
        me = self.gcs.config.client_id
        for_me = msg.client_id in ("", me)
        if (msg.kind in FAILSAFE_KINDS and for_me) or (msg.kind == "setpoint_rejected" and msg.client_id == me):
            self.failures.append(f"{msg.kind}: {msg.detail}")
            del self.failures[:-self.MAX_EVENTS]
        if msg.kind in ("lifecycle", "setpoint_ignored"):
            log.info("%s: %s (%s)", self.id, msg.kind, msg.detail)
        else:
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

    # -- targets ---------------------------------------------------------------------
    def target(self) -> Target | None:
        """What to stream now, or None (no position known: nothing safe to send)."""
        if self._frozen is not None:
            return self._frozen
        s = self.state
        if s is None or not s.connected or not all(math.isfinite(v) for v in s.position):
            return None
        x, y, z = (float(v) for v in s.position)
        alt = -abs(self.gcs.config.altitude)
        toward = min(max(alt, z - MAX_LEAD_M), z + MAX_LEAD_M)   # climb (or descend) from where it is
        if not self.session_active:
            self._anchor = None
            self._hover = Target(x, y, toward, self._hover.yaw if self._hover else 0.0)
            return self._hover
        if self._hover is None:
            self._hover = Target(x, y, toward)
        if not self.fly:   # session active, pattern not started: hold x, y, keep climbing
            self._hover = Target(self._hover.x, self._hover.y, toward, self._hover.yaw)
            return self._hover
        if self._anchor is None:
            self._anchor, self._t0 = self._hover, time.monotonic()
        p0, p = self.gcs.pattern(0.0), self.gcs.pattern(time.monotonic() - self._t0)
        return Target(self._anchor.x + p.x - p0.x, self._anchor.y + p.y - p0.y,
                      min(max(p.z, z - MAX_LEAD_M), z + MAX_LEAD_M), p.yaw)

    def start_pattern(self) -> None:
        self.fly, self._anchor, self._frozen = True, None, None

    def freeze(self) -> None:
        """Keep sending the current target (a jump back to the start would be refused)."""
        self._frozen = self.target()
        self.fly = False

    # -- commands --------------------------------------------------------------------
    def command(self, name: str, value: float = 0.0, text: str = "", force: bool = False,
                timeout: float = 8.0) -> CommandResult:
        """Send a command and wait for the drone's answer; errors come back as a failed result."""
        try:
            return self.commands.call(Command(name, float(value), text, force, self.gcs.config.client_id),
                                      timeout=timeout)
        except ServiceCallError as exc:
            return CommandResult(False, f"{type(exc).__name__}: {exc}", "")

    def send_setpoint(self, t: Target) -> None:
        sent = self.setpoint_pub.publish(DroneSetpoint(Header.now(seq=self.setpoints_sent), self.gcs.config.client_id,
                                                       t.x, t.y, t.z, t.yaw, False))
        self.sent["setpoint"].record(sent.seq, sent.stamp_ns)
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
        self.pattern = make_pattern(config.pattern, config.altitude, config.size, config.speed)
        self.streaming = True
        # The companion knows its controller is alive by this token (dropped when the session ends).
        self._token = node.session.liveliness().declare_token(f"{CONTROL_TOKEN_PREFIX}/{config.client_id}")
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

    def take_control(self) -> dict[str, CommandResult]:
        """Explicit takeover (``--take-control``): the previous GCS is told by the drone."""
        return {d.id: d.command("take_control", force=True) for d in list(self.drones.values())}

    def release_control(self, timeout: float = 2.0) -> None:
        """On exit: give control back at once instead of leaving it to the liveliness lease."""
        for d in list(self.drones.values()):
            if d.in_control:
                res = d.command("release_control", timeout=timeout)
                log.info("%s: release_control: %s", d.id, res.message)

    def _stream(self) -> None:
        if not self.streaming:
            return
        for drone in list(self.drones.values()):
            t = drone.target()
            if t is not None:
                drone.send_setpoint(t)
    def _save_images(self) -> None:
        from PIL import Image as PILImage
        assert self.config.save_image is not None
        for drone in list(self.drones.values()):
            if drone.latest_frame is not None:
                path = self.config.save_image
                if len(self.drones) > 1:
                    path = path.with_name(f"{path.stem}_{drone.id}{path.suffix}")
                PILImage.fromarray(drone.latest_frame).save(path)
