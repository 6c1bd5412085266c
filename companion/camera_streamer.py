"""The drone's camera on ``<id>/image``, as the stream profile's image mode carries it.

The mode's sender comes from the library's registry (``zenoh_robot.image``: raw, jpeg, sliced,
fec). Frames are numbered as a camera driver numbers them (``header.seq``), and every frame (and
strip) sent is recorded, as the sender numbers it, for the experiment's fresh-frame figures.

Threads: its own ``camera`` thread reads, encodes and publishes (never the executor that serves
setpoints), at a lower OS priority than the rest (priority.py); ``start`` and ``close`` are called by the
owner. The rate follows a live `param set`.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from zenoh_robot import Node
from zenoh_robot.image import image_publisher
from zenoh_robot.msgs import Header
from zenoh_robot.qos import QoSProfile
from zenoh_robot.tools.stream_metrics import StreamRecorder

from .camera import RateKeeper, open_source
from .config import CompanionConfig
from .priority import lower_thread_priority

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had
CAMERA_NICE = 10   # the encoder runs on what the setpoint path, the state and (on a shared machine) the GCS leave


class CameraStreamer:
    def __init__(self, node: Node, topic: str, qos: QoSProfile, config: Callable[[], CompanionConfig],
                 sent_frames: StreamRecorder, sent_strips: StreamRecorder) -> None:
        self._config = config             # live: a `param set` replaces the config
        self._sent_frames, self._sent_strips = sent_frames, sent_strips
        profile = config().profile
        self.publisher = image_publisher(profile.image_mode, node, topic, qos, quality=profile.jpeg_quality)
        self._seq = 0   # the frame's header.seq
        # Called with each frame after it went out on the contract's stream (the ROS 2 topics: ros2_streams.py)
        self.frame_listeners: list[Callable[[Any], None]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.nice: int | None = None   # the camera thread's nice value once lowered (None: not possible here)

    @property
    def frames_sent(self) -> int:
        """Frames sent so far (the camera thread's count: read as a plain int)."""
        return self._seq

    def set_loss(self) -> Callable[[float], None] | None:
        """Where the measured loss goes (FEC parity follows it), or None when nothing adapts."""
        return self.publisher.set_loss if self.publisher.follows_loss else None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="camera", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def _loop(self) -> None:
        self.nice = lower_thread_priority(CAMERA_NICE)
        if self.nice is None:
            log.info("camera: its thread's priority cannot be lowered here; it competes with the setpoint path")
        cfg = self._config()
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
                self.publish_frame(frame)
                for listener in self.frame_listeners:
                    listener(frame)
                if self._config().camera_rate_hz != cfg.camera_rate_hz:   # a live `param set` (a GCS's downlink)
                    cfg = self._config()
                    rate = RateKeeper(cfg.camera_rate_hz)
                rate.wait()
        finally:
            source.close()

    def publish_frame(self, frame: Any) -> None:
        head = Header.now(frame_id="camera", seq=self._seq)
        self._seq += 1
        sent = self.publisher.send(frame, head)
        self._sent_frames.record(sent.frame, sent.stamp_ns)
        for piece in sent.pieces:
            self._sent_strips.record(piece, sent.stamp_ns)
