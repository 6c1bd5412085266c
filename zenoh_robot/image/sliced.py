"""The sliced mode: JPEG strips that each fit one packet, a lost packet costing one strip.

A raw 320x240 RGB frame is 230 KB: ~160 packets, and a best-effort message is lost
whole when any one of them is. Here each frame is cut into horizontal strips, each
strip an independent JPEG small enough for one UDP datagram, so a lost packet costs
one strip, not the frame: the receiver shows the same strip of the frame before in its
place. Frames are never queued behind each other: a slice of a newer frame closes the
current one (shown as it is) and older slices are dropped (``base.LatestFrame``).

Usage (any ``Image`` stream)::

    pub = ImagePublisher(node, "image", qos.IMAGE, quality=70)
    pub.publish(Image.from_array(frame, header=Header.now("camera", seq=n)))   # or pub.publish(ndarray)
    pub.get_subscription_count()                    # pub.publisher: the underlying Publisher
    view = SliceReceiver(node, "image")             # view.latest() -> (ndarray, FrameInfo), decoded then
    ImageSubscription(node, "image", on_image)      # or on_image(Image, FrameInfo) with every frame

The receiver gets the publisher's ``Image.header`` unchanged (stamp, frame_id, seq as set;
a bare ndarray gets ``Header(now, "", frame number)``). The transport's own frame counter
travels in ``ImageSlice.frame``. ``FrameInfo`` says how honest the picture is: ``complete``
(every strip of this frame, all fresh), ``patched`` (some strips shown come from older
frames), ``fresh_fraction``, ``oldest_strip_age_ms`` (delivery - publication of the oldest
strip shown), ``frame``, ``slices_received``/``slice_count``.

Bounded: the strips of one geometry, at most ``MAX_SLICES`` of at most ``MAX_SLICE_BYTES``;
a slice that cannot belong to any frame (its JPEG header included) is counted and dropped
before it is stored.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..jpeg import decode_jpeg, encode_jpeg, jpeg_size
from ..message import Message, message, ros_field
from ..msgs import Header, Image
from ..qos import IMAGE, QoSProfile
from .base import (
    IMAGE_TYPE,
    MAX_SLICES,
    FrameInfo,
    FrameRecords,
    ImageReceiver,
    ImageSender,
    SentFrame,
    check_quality,
    frame_array,
    publish_paced,
    sample_stamps,
    stamp_age_ms,
)

DEFAULT_SLICE_BYTES = 1100   # under one UDP datagram with Zenoh's headers at a 1500-byte MTU
# Receive-side bounds: what a slice may claim before anything is allocated for it.
MAX_SLICE_BYTES = 1 << 20
MAX_SIDE = 16384
MAX_FRAME_BYTES = 64 << 20


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


class ImagePublisher(ImageSender):
    """Publishes ``Image`` frames as independently decodable JPEG slices."""

    def __init__(self, node: Any, topic: str, qos: QoSProfile = IMAGE, *, quality: int = 70,
                 slice_rows: int | None = None, max_slice_bytes: int = DEFAULT_SLICE_BYTES,
                 pace_s: float = 0.0015) -> None:
        self.quality = check_quality(quality)
        self.max_slice_bytes = max_slice_bytes
        self._slice_rows = slice_rows
        # A frame is a burst of slices; Zenoh's TX queue holds two batches per priority and DROP
        # congestion control discards what does not fit within 1 ms, i.e. most of the burst.
        # BLOCK (KEEP_ALL) makes the camera thread wait microseconds instead; latest-frame
        # semantics are kept on the receiving side.
        self.publisher = node.create_publisher(ImageSlice, topic, qos.replace(history="keep_all", depth=0))
        self.frames = 0
        self.last_count = 0      # slices of the last frame published
        self.oversize_slices = 0  # slices that did not fit one datagram (Zenoh fragments them)
        # Zenoh batches messages sent within 1 ms of each other into one datagram, and on the
        # multicast transport a batch is not bounded by batch_size: a burst of slices would
        # leave as one large, IP-fragmented datagram that any lost fragment destroys. Spacing
        # the slices past the batching window keeps each in its own datagram.
        self.pace_s = pace_s

    def publish(self, frame: Image | np.ndarray, header: Header | None = None) -> int:
        """Send one frame; returns its frame number (the slices' ``frame``)."""
        return self.send(frame, header).frame

    def send(self, frame: Image | np.ndarray, header: Header | None = None) -> SentFrame:
        pieces = self.encode(frame, header)
        publish_paced(self.publisher, pieces, self.pace_s)
        self.last_count = len(pieces)
        self.frames += 1
        n = pieces[0].frame
        return SentFrame(n, pieces[0].header.stamp, tuple(n * MAX_SLICES + s.index for s in pieces))

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
            data = encode_jpeg(arr[i * rows:(i + 1) * rows], self.quality)
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


def slice_error(s: ImageSlice) -> str | None:
    """Why a slice cannot be part of any frame: checked before anything is allocated or decoded
    (the JPEG's own header too: a strip wider or taller than its place, or of a colour the frame
    is not, would be refused by the decoder later, after taking a good strip's place)."""
    if s.encoding not in ("rgb8", "mono8"):
        return f"encoding {s.encoding!r}"
    if not (1 <= s.count <= MAX_SLICES and 0 <= s.index < s.count):
        return f"slice {s.index} of {s.count}"
    if not (1 <= s.width <= MAX_SIDE and 1 <= s.height <= MAX_SIDE
            and s.width * s.height * (1 if s.encoding == "mono8" else 3) <= MAX_FRAME_BYTES):
        return f"frame of {s.width}x{s.height}"
    if not (0 <= s.row < s.height and len(s.data) <= MAX_SLICE_BYTES):
        return f"row {s.row} / {len(s.data)} bytes"
    size = jpeg_size(s.data)
    if size is None:
        return "not a JPEG"
    w, h, components = size
    if w > s.width or h > s.height - s.row or components not in ((1,) if s.encoding == "mono8" else (1, 3)):
        return f"strip of {w}x{h}x{components} at row {s.row} of a {s.width}x{s.height} {s.encoding} frame"
    return None


class SliceReceiver(ImageReceiver):
    """Slices in; shows the newest strip received at each strip index when the last frame closed
    (its next one began, or its last strip arrived); decodes, on demand, only strips not yet drawn."""

    message_type = ImageSlice
    burst = 256     # a frame's slices come in a burst: the queue holds a frame's worth

    def __init__(self, node: Any = None, topic: str = "", qos: QoSProfile = IMAGE, *,
                 records: FrameRecords | None = None,
                 callback: Callable[[Image, FrameInfo], None] | None = None,
                 topic_statistics: Any = None) -> None:
        # Executor side, under the lock.
        self._strips: dict[int, tuple[ImageSlice, int]] = {}     # index -> (newest slice, its publication ns)
        self._geometry: tuple[int, int, int, str] | None = None  # count, width, height, encoding
        self._got: set[int] = set()
        self._closed = True
        self._head: ImageSlice | None = None
        self._source_ns = 0          # the current frame's first slice: its publication stamp
        self._received_ns = 0
        self._publisher_id = 0
        self.bad_slices = 0
        self.stale_slices = 0
        # Decoder side, under the decode lock.
        self._canvas: np.ndarray | None = None
        self._drawn: dict[int, tuple[int, int]] = {}   # index -> (frame, publication ns) of the strip drawn
        self._drawn_count = 0
        super().__init__(node, topic, qos, records=records, callback=callback, topic_statistics=topic_statistics)

    def _file(self, s: ImageSlice, info: Any) -> None:
        if slice_error(s) is not None:
            self.bad_slices += 1
            return
        publisher_id, source, received = sample_stamps(info)
        self.records.piece(s.frame * MAX_SLICES + s.index, s.header.stamp, received)
        frame = s.frame
        if self._order.is_stale(frame):
            self.stale_slices += 1
            return
        geometry = (s.count, s.width, s.height, s.encoding)
        if frame != self._order.frame:
            if not self._closed:
                self._close()
            self.strips_expected += self._order.begin(frame) * s.count
            if geometry != self._geometry:
                self._strips, self._geometry = {}, geometry
            self._got, self._closed, self._head = set(), False, s
            self._source_ns, self._publisher_id = source or s.header.stamp, publisher_id
            self._begin(frame, s.header.stamp, received, stamp_age_ms(source, received))
        elif geometry != self._geometry:
            self.bad_slices += 1      # disagrees with the frame's first slice
            return
        if s.index in self._got:
            return                    # a duplicate
        self._got.add(s.index)
        self._strips[s.index] = (s, self._source_ns)
        self._received_ns = received
        if len(self._got) == s.count:
            self.complete += 1
            self._close()
            self.records.whole(frame, s.header.stamp, received)

    def _close(self) -> None:
        """The frame being filled is over: what the viewer shows from now on (a dict copy, no pixels)."""
        head = self._head
        assert head is not None and self._geometry is not None
        self._closed = True
        count = self._geometry[0]
        # Counted when a frame closes, so the figures never see a frame half-filled.
        self.strips_fresh += len(self._got)
        self.strips_expected += count
        shown = dict(self._strips)
        stamps = [t for _, t in shown.values() if t]
        info = FrameInfo(self._publisher_id, head.header.seq, self._source_ns, self._received_ns, IMAGE_TYPE,
                         frame=self._order.frame, slices_received=len(self._got), slice_count=count,
                         oldest_stamp_ns=min(stamps, default=0), patched=len(shown) > len(self._got))
        self._show(shown, info, head.header)

    def _decode(self, shown: dict[int, tuple[ImageSlice, int]]) -> np.ndarray:
        first = next(iter(shown.values()))[0]
        channels = 1 if first.encoding == "mono8" else 3
        shape = (first.height, first.width) if channels == 1 else (first.height, first.width, channels)
        if self._canvas is None or self._canvas.shape != shape or first.count != self._drawn_count:
            # First frame, or strips cut differently: missing strips black.
            self._canvas, self._drawn, self._drawn_count = np.zeros(shape, dtype=np.uint8), {}, first.count
        canvas = self._canvas
        for index, (s, stamp) in shown.items():
            if self._drawn.get(index) == (s.frame, stamp):
                continue                  # this strip is on the canvas already
            try:
                strip = decode_jpeg(s.data, max_width=s.width, max_height=s.height - s.row)
                if strip.ndim == 2 and channels == 3:
                    strip = np.repeat(strip[:, :, None], 3, axis=2)
                if strip.ndim != canvas.ndim or (strip.ndim == 3 and strip.shape[2] != channels):
                    raise ValueError(f"strip of shape {strip.shape} in a {s.encoding} frame")
                canvas[s.row:s.row + strip.shape[0], :strip.shape[1]] = strip
                self._drawn[index] = (s.frame, stamp)
            except Exception:   # a damaged strip: counted, the rest of the frame still shown
                self.bad_slices += 1
        return canvas


class ImageSubscription(SliceReceiver):
    """``callback(Image, FrameInfo)`` with every frame as it closes, decoded on the executor (as an
    rclpy subscription); a viewer that shows the newest frame wants :class:`SliceReceiver` instead."""

    def __init__(self, node: Any, topic: str, callback: Callable[[Image, FrameInfo], None],
                 qos: QoSProfile = IMAGE) -> None:
        super().__init__(node, topic, qos, callback=callback)

    @property
    def frames_complete(self) -> int:
        return self.complete

    @property
    def frames_patched(self) -> int:
        return self.patched
