"""Images that survive loss: JPEG slices that each fit one packet, and latest-frame reassembly.

A raw 320x240 RGB frame is 230 KB: ~160 packets, and a best-effort message is lost
whole when any one of them is. Here each frame is cut into horizontal strips, each
strip an independent JPEG small enough for one UDP datagram, so a lost packet costs
one strip, not the frame: the subscriber patches it with the same strip of the frame
before. Frames are never queued behind each other: a slice of a newer frame closes
the current one (delivered as it is) and older slices are dropped.

Usage (any ``Image`` stream)::

    pub = ImagePublisher(node, "image", qos.IMAGE, quality=70)
    pub.publish(Image.from_array(frame))            # or pub.publish(ndarray)
    ImageSubscription(node, "image", on_image)      # on_image(Image, FrameInfo)
"""
from __future__ import annotations

import io
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .message import Message, message, ros_field
from .msgs import Header, Image
from .qos import IMAGE, QoSProfile

DEFAULT_SLICE_BYTES = 1100   # under one UDP datagram with Zenoh's headers at a 1500-byte MTU
# Receive-side bounds: what a slice may claim before anything is allocated for it.
MAX_SLICE_BYTES = 1 << 20
MAX_SLICES = 4096
MAX_SIDE = 16384
MAX_FRAME_BYTES = 64 << 20
STALE_FRAMES_TO_RESTART = 2  # older frames in a row, each newer than the last: the stream restarted


@message(name="zenoh_robot/ImageSlice")
class ImageSlice(Message):
    header: Header = None  # type: ignore[assignment]    # capture stamp; header.seq is the frame number
    index: int = ros_field("uint16", default=0)      # slice number in the frame
    count: int = ros_field("uint16", default=0)      # slices in the frame
    row: int = ros_field("uint32", default=0)        # first image row of this slice
    height: int = ros_field("uint32", default=0)     # whole frame
    width: int = ros_field("uint32", default=0)
    encoding: str = "rgb8"                   # of the decoded frame: rgb8 or mono8
    data: bytes = b""                        # one baseline JPEG of rows [row, row + its height)

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@dataclass(slots=True)
class FrameInfo:
    frame: int
    slices_received: int
    slice_count: int
    age_ms: float            # delivery time - capture stamp

    @property
    def complete(self) -> bool:
        return self.slices_received == self.slice_count


def encode_strip(rows: np.ndarray, quality: int) -> bytes:
    buf = io.BytesIO()
    from PIL import Image as PILImage  # the [image] extra; only image paths need it

    PILImage.fromarray(rows).save(buf, format="JPEG", quality=quality, optimize=False)
    return buf.getvalue()


def decode_strip(data: bytes, max_width: int | None = None, max_height: int | None = None) -> np.ndarray:
    """One JPEG strip as an array; ValueError, before decoding, if its header claims more pixels
    than ``max_width`` x ``max_height`` (a small packet must not inflate to gigabytes)."""
    from PIL import Image as PILImage

    with PILImage.open(io.BytesIO(data)) as im:
        w, h = im.size
        if (max_width is not None and w > max_width) or (max_height is not None and h > max_height):
            raise ValueError(f"strip of {w}x{h} does not fit the frame")
        return np.asarray(im)


def frame_array(frame: Image | np.ndarray, header: Header | None, who: str) -> tuple[np.ndarray, Header | None]:
    """A camera frame as an HxW or HxWx3 uint8 array, and the header to stamp it with."""
    if isinstance(frame, Image):
        header = header or frame.header
        arr = frame.to_array()
    else:
        arr = frame
    if arr.dtype != np.uint8 or arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise ValueError(f"{who} takes HxW or HxWx3 uint8 frames, got {arr.dtype} {arr.shape}")
    return arr, header


def publish_paced(publisher: Any, pieces: list[Any], pace_s: float) -> None:
    """Publish a frame's pieces ``pace_s`` apart, past Zenoh's batching window (see ImagePublisher)."""
    for i, piece in enumerate(pieces):
        if i and pace_s:
            time.sleep(pace_s)
        publisher.publish(piece)


class ImagePublisher:
    """Publishes ``Image`` frames as independently decodable JPEG slices."""

    def __init__(self, node: Any, topic: str, qos: QoSProfile = IMAGE, *, quality: int = 70,
                 slice_rows: int | None = None, max_slice_bytes: int = DEFAULT_SLICE_BYTES,
                 pace_s: float = 0.0015) -> None:
        if not 1 <= quality <= 95:
            raise ValueError(f"JPEG quality must be 1..95, got {quality}")
        self.quality = quality
        self.max_slice_bytes = max_slice_bytes
        self._slice_rows = slice_rows
        # A frame is a burst of slices; Zenoh's TX queue holds two batches per priority and DROP
        # congestion control discards what does not fit within 1 ms, i.e. most of the burst.
        # BLOCK (KEEP_ALL) makes the camera thread wait microseconds instead; latest-frame
        # semantics are kept on the receiving side.
        self._pub = node.create_publisher(ImageSlice, topic, qos.replace(history="keep_all", depth=0))
        self.frames = 0
        self.last_count = 0      # slices of the last frame published
        self.oversize_slices = 0
        # Zenoh batches messages sent within 1 ms of each other into one datagram, and on the
        # multicast transport a batch is not bounded by batch_size: a burst of slices would
        # leave as one large, IP-fragmented datagram that any lost fragment destroys. Spacing
        # the slices past the batching window keeps each in its own datagram.
        self.pace_s = pace_s   # slices that did not fit one datagram (Zenoh fragments them)

    def publish(self, frame: Image | np.ndarray, header: Header | None = None) -> None:
        pieces = self.encode(frame, header)
        publish_paced(self._pub, pieces, self.pace_s)
        self.last_count = len(pieces)
        self.frames += 1

    def encode(self, frame: Image | np.ndarray, header: Header | None = None) -> list[ImageSlice]:
        """The slices of one frame (numbered ``self.frames``), without publishing them."""
        arr, header = frame_array(frame, header, "ImagePublisher")
        h, w = arr.shape[:2]
        encoding = "mono8" if arr.ndim == 2 else "rgb8"
        rows = self._slice_rows or self._rows_for(w, arr.ndim)
        count = (h + rows - 1) // rows
        head = header or Header()
        head = Header(head.stamp or time.time_ns(), head.frame_id, self.frames)
        pieces = []
        for i in range(count):
            data = encode_strip(arr[i * rows:(i + 1) * rows], self.quality)
            if len(data) > self.max_slice_bytes:
                self.oversize_slices += 1
            pieces.append(ImageSlice(head, i, count, i * rows, h, w, encoding, data))
        return pieces

    def _rows_for(self, width: int, ndim: int) -> int:
        # JPEG at quality ~70 costs roughly 0.5-1 bit per pixel on camera images; 8-row
        # multiples keep MCU boundaries clean. Aim for the datagram budget with margin.
        bytes_per_row = width * (3 if ndim == 3 else 1) * self.quality / 1600
        rows = int(self.max_slice_bytes * 0.8 / max(bytes_per_row, 1)) // 8 * 8
        return max(8, rows)


class ImageSubscription:
    """Reassembles slices into frames with latest-frame semantics; ``callback(Image, FrameInfo)``."""

    def __init__(self, node: Any, topic: str, callback: Callable[[Image, FrameInfo], None],
                 qos: QoSProfile = IMAGE) -> None:
        self.callback = callback
        # Slices of one frame arrive in a burst: the queue must hold a frame's worth.
        self.sub = node.create_subscription(ImageSlice, topic, self._on_slice, qos.replace(depth=max(qos.depth, 256)))
        self._canvas: np.ndarray | None = None
        self._frame = -1
        self._stamp = 0
        self._got: set[int] = set()
        self._count = 0
        self._delivered = True
        self.frames_delivered = 0
        self.frames_complete = 0
        self.stale_slices = 0
        self.bad_slices = 0
        self._stale_run = 0          # distinct older frames seen in a row since the current one began
        self._stale_last = -1

    @staticmethod
    def _slice_error(s: ImageSlice) -> str | None:
        """Why a slice cannot be part of any frame (checked before anything is allocated)."""
        if s.encoding not in ("rgb8", "mono8"):
            return f"encoding {s.encoding!r}"
        if not (1 <= s.count <= MAX_SLICES and 0 <= s.index < s.count):
            return f"slice {s.index} of {s.count}"
        if not (1 <= s.width <= MAX_SIDE and 1 <= s.height <= MAX_SIDE
                and s.width * s.height * (1 if s.encoding == "mono8" else 3) <= MAX_FRAME_BYTES):
            return f"frame of {s.width}x{s.height}"
        if not (0 <= s.row < s.height and len(s.data) <= MAX_SLICE_BYTES):
            return f"row {s.row} / {len(s.data)} bytes"
        return None

    def _on_slice(self, s: ImageSlice, info: Any = None) -> None:
        if self._slice_error(s) is not None:
            self.bad_slices += 1
            return
        frame = s.header.seq
        if frame < self._frame:
            # Older than the current frame: a late slice, or the current frame was forged far ahead
            # (or the publisher restarted). Older frames that keep coming, each newer than the one
            # before, are the live stream: follow it after STALE_FRAMES_TO_RESTART of them, so a
            # forged frame number cannot blind the viewer for more than that.
            if frame > self._stale_last:
                self._stale_run += 1
                self._stale_last = frame
            if self._stale_run < STALE_FRAMES_TO_RESTART:
                self.stale_slices += 1
                return
        if frame != self._frame:
            if not self._delivered:
                self._deliver()
            self._start(s)
        elif (s.count != self._count or self._canvas is None
              or self._canvas.shape[:2] != (s.height, s.width)
              or (self._canvas.ndim == 2) != (s.encoding == "mono8")):
            self.bad_slices += 1     # disagrees with the frame's first slice
            return
        try:
            assert self._canvas is not None
            strip = decode_strip(s.data, max_width=s.width, max_height=s.height - s.row)
            channels = 1 if s.encoding == "mono8" else 3
            if strip.ndim == 2 and channels == 3:
                strip = np.repeat(strip[:, :, None], 3, axis=2)
            if strip.ndim != self._canvas.ndim or (strip.ndim == 3 and strip.shape[2] != channels):
                raise ValueError(f"strip of shape {strip.shape} in a {s.encoding} frame")
            self._canvas[s.row:s.row + strip.shape[0], :strip.shape[1]] = strip
        except Exception:
            self.bad_slices += 1
            return
        self._got.add(s.index)
        if len(self._got) >= self._count and not self._delivered:
            self._deliver()

    def _start(self, s: ImageSlice) -> None:
        shape = (s.height, s.width) if s.encoding == "mono8" else (s.height, s.width, 3)
        if self._canvas is None or self._canvas.shape != shape:
            self._canvas = np.zeros(shape, dtype=np.uint8)   # first frame: missing strips black
        self._frame, self._stamp, self._count = s.header.seq, s.header.stamp, s.count
        self._got = set()
        self._stale_run, self._stale_last = 0, -1
        self._delivered = False

    def _deliver(self) -> None:
        assert self._canvas is not None
        self._delivered = True
        complete = len(self._got) >= self._count
        self.frames_delivered += 1
        self.frames_complete += complete
        img = Image.from_array(self._canvas, header=Header(self._stamp, "", self._frame))
        age = (time.time_ns() - self._stamp) / 1e6 if self._stamp else float("nan")
        self.callback(img, FrameInfo(self._frame, len(self._got), self._count, age))
