"""Images that survive loss: JPEG slices that each fit one packet, and latest-frame reassembly.

A raw 320x240 RGB frame is 230 KB: ~160 packets, and a best-effort message is lost
whole when any one of them is. Here each frame is cut into horizontal strips, each
strip an independent JPEG small enough for one UDP datagram, so a lost packet costs
one strip, not the frame: the subscriber patches it with the same strip of the frame
before. Frames are never queued behind each other: a slice of a newer frame closes
the current one (delivered as it is) and older slices are dropped.

Usage (any ``Image`` stream)::

    pub = ImagePublisher(node, "image", qos.IMAGE, quality=70)
    pub.publish(Image.from_array(frame, header=Header.now("camera", seq=n)))   # or pub.publish(ndarray)
    pub.get_subscription_count()                    # pub.publisher: the underlying Publisher
    ImageSubscription(node, "image", on_image)      # on_image(Image, FrameInfo)

The subscriber gets the publisher's ``Image.header`` unchanged (stamp, frame_id, seq as set;
a bare ndarray gets ``Header(now, "", frame number)``). The transport's own frame counter
travels in ``ImageSlice.frame``. ``FrameInfo`` is a ``MessageInfo`` (publisher_id, seq = the
user's header.seq, source_stamp_ns = when the frame's first slice was published,
received_stamp_ns = delivery, type_name, age_ms) plus what a patched picture needs said:
``complete`` (every strip of this frame, all fresh), ``patched`` (some strips shown come from
older frames), ``fresh_fraction``, ``oldest_strip_age_ms`` (delivery - publication of the
oldest strip shown), ``frame``, ``slices_received``/``slice_count``.
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
from .subscription import MessageInfo

DEFAULT_SLICE_BYTES = 1100   # under one UDP datagram with Zenoh's headers at a 1500-byte MTU
# Receive-side bounds: what a slice may claim before anything is allocated for it.
MAX_SLICE_BYTES = 1 << 20
MAX_SLICES = 4096
MAX_SIDE = 16384
MAX_FRAME_BYTES = 64 << 20
STALE_FRAMES_TO_RESTART = 2  # older frames in a row, each newer than the last: the stream restarted


@message(name="zenoh_robot/ImageSlice")
class ImageSlice(Message):
    header: Header = None  # type: ignore[assignment]    # the user's Image header, unchanged
    frame: int = ros_field("uint64", default=0)      # the transport's frame counter (reassembly, latest-frame)
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


IMAGE_TYPE = "sensor_msgs/Image"


@dataclass(slots=True)
class FrameInfo(MessageInfo):
    """A delivered frame: MessageInfo's fields (``seq`` is the user's header.seq) and how fresh it is.

    ``source_stamp_ns`` is when the frame's first piece was published (the envelope's stamp; the
    header's stamp when fed without one), ``received_stamp_ns`` when the frame was delivered.
    """
    frame: int = 0                 # the transport's frame counter (ImageSlice.frame)
    slices_received: int = 0       # strips of this frame shown (fresh)
    slice_count: int = 0           # strips in the frame
    oldest_stamp_ns: int = 0       # publication stamp of the oldest strip shown (0: none known)
    patched: bool = False          # some strips shown come from older frames

    @property
    def age_ms(self) -> float:
        if not self.source_stamp_ns:
            return float("nan")
        return (self.received_stamp_ns - self.source_stamp_ns) / 1e6

    @property
    def complete(self) -> bool:
        """Every strip of this frame arrived: the picture is entirely this frame."""
        return self.slice_count > 0 and self.slices_received >= self.slice_count

    @property
    def fresh_fraction(self) -> float:
        return self.slices_received / self.slice_count if self.slice_count else 0.0

    @property
    def oldest_strip_age_ms(self) -> float:
        """Delivery - publication of the oldest strip in the picture (== age_ms when complete)."""
        oldest = self.oldest_stamp_ns or self.source_stamp_ns
        return (self.received_stamp_ns - oldest) / 1e6 if oldest else float("nan")


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
        header = header if header is not None else frame.header
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
        self.publisher = node.create_publisher(ImageSlice, topic, qos.replace(history="keep_all", depth=0))
        self.frames = 0
        self.last_count = 0      # slices of the last frame published
        self.oversize_slices = 0
        # Zenoh batches messages sent within 1 ms of each other into one datagram, and on the
        # multicast transport a batch is not bounded by batch_size: a burst of slices would
        # leave as one large, IP-fragmented datagram that any lost fragment destroys. Spacing
        # the slices past the batching window keeps each in its own datagram.
        self.pace_s = pace_s   # slices that did not fit one datagram (Zenoh fragments them)

    def get_subscription_count(self) -> int:
        """Subscriptions matched to the slice publisher (as rclpy's Publisher.get_subscription_count)."""
        return int(self.publisher.get_subscription_count())

    def publish(self, frame: Image | np.ndarray, header: Header | None = None) -> int:
        """Send one frame; returns its frame number (the slices' ``frame``)."""
        pieces = self.encode(frame, header)
        publish_paced(self.publisher, pieces, self.pace_s)
        self.last_count = len(pieces)
        self.frames += 1
        return pieces[0].frame

    def encode(self, frame: Image | np.ndarray, header: Header | None = None) -> list[ImageSlice]:
        """The slices of one frame (numbered ``self.frames``), without publishing them.

        The header goes out as given (``header``, else the Image's); a bare ndarray gets
        ``Header(now, "", frame number)`` so it still carries a capture stamp."""
        arr, header = frame_array(frame, header, "ImagePublisher")
        h, w = arr.shape[:2]
        encoding = "mono8" if arr.ndim == 2 else "rgb8"
        rows = self._slice_rows or self._rows_for(w, arr.ndim)
        count = (h + rows - 1) // rows
        head = header if header is not None else Header(time.time_ns(), "", self.frames)
        pieces = []
        for i in range(count):
            data = encode_strip(arr[i * rows:(i + 1) * rows], self.quality)
            if len(data) > self.max_slice_bytes:
                self.oversize_slices += 1
            pieces.append(ImageSlice(head, self.frames, i, count, i * rows, h, w, encoding, data))
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
        # Two required arguments: the subscription passes each slice's MessageInfo (publisher, stamps).
        self.sub = node.create_subscription(ImageSlice, topic, lambda s, info: self._on_slice(s, info),
                                            qos.replace(depth=max(qos.depth, 256)))
        self._canvas: np.ndarray | None = None
        self._frame = -1
        self._header = Header()
        self._source_ns = 0          # the current frame's first slice: its publication stamp
        self._publisher_id = 0
        self._got: set[int] = set()
        self._count = 0
        self._delivered = True
        # Per strip index of the canvas: publication stamp of the frame it was drawn from (bounded by
        # MAX_SLICES; reset with the canvas's geometry), for `patched` and the oldest strip's age.
        self._strip_stamp: dict[int, int] = {}
        self.frames_delivered = 0
        self.frames_complete = 0
        self.frames_patched = 0
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
        frame = s.frame
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
            self._start(s, info)
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
        self._strip_stamp[s.index] = self._source_ns
        if len(self._got) >= self._count and not self._delivered:
            self._deliver()

    def _start(self, s: ImageSlice, info: Any) -> None:
        shape = (s.height, s.width) if s.encoding == "mono8" else (s.height, s.width, 3)
        if self._canvas is None or self._canvas.shape != shape:
            self._canvas = np.zeros(shape, dtype=np.uint8)   # first frame: missing strips black
            self._strip_stamp = {}
        elif s.count != self._count:
            self._strip_stamp = {}   # strips cut differently: old pixels stay, their ages are unknown
        self._frame, self._header, self._count = s.frame, s.header, s.count
        self._source_ns = int(getattr(info, "source_stamp_ns", 0)) or s.header.stamp
        self._publisher_id = int(getattr(info, "publisher_id", 0))
        self._got = set()
        self._stale_run, self._stale_last = 0, -1
        self._delivered = False

    def _deliver(self) -> None:
        assert self._canvas is not None
        self._delivered = True
        shown = [self._strip_stamp[i] for i in range(self._count) if i in self._strip_stamp]
        info = FrameInfo(self._publisher_id, self._header.seq, self._source_ns, time.time_ns(), IMAGE_TYPE,
                         frame=self._frame, slices_received=len(self._got), slice_count=self._count,
                         oldest_stamp_ns=min((t for t in shown if t), default=0),
                         patched=len(shown) > len(self._got))
        self.frames_delivered += 1
        self.frames_complete += info.complete
        self.frames_patched += info.patched
        img = Image.from_array(self._canvas, header=Header(self._header.stamp, self._header.frame_id,
                                                           self._header.seq))
        self.callback(img, info)
