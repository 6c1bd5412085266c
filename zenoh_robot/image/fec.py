"""The fec mode: images that arrive whole or not at all, one JPEG per frame in shares plus parity.

Cutting a frame into independent JPEG strips (the sliced mode) turns one lost packet
into one stale strip, but a frame then depends on ~8 packets and is whole only if all of
them arrive: at 30 % loss ~1 % of frames are. Here a frame is one JPEG (smaller than the
strips' sum: every strip repeats the JPEG headers), split into ``k`` MTU-sized shares,
and Reed-Solomon parity (zfec, as wfb-ng does) brings the block to ``n`` shares of which
*any* ``k`` rebuild the frame. A frame is whole iff >= k of its n shares arrive, and a
shown frame is always entirely fresh.

``n`` follows the loss: the smallest n with P(>= k of n arrive) >= ``target`` under
independent loss p (binomial tail), clamped to ``max_expansion`` x k (a bandwidth ceiling)
and zfec's 256. p is a configured value or the receiver's measurement fed back
(``loss_feedback.LossMonitor``: ``monitor.adapt(image_pub.set_loss)``).

Usage::

    pub = FecImagePublisher(node, "image", qos.IMAGE, loss=0.1)
    pub.publish(frame)                                   # HxW or HxWx3 uint8
    pub.get_subscription_count()                         # pub.publisher: the underlying Publisher
    view = FecReceiver(node, "image")                    # view.latest() -> (ndarray, FecFrameInfo)
    FecImageSubscription(node, "image", on_image)        # or on_image(Image, FecFrameInfo), every frame

As the sliced mode: the user's ``Image.header`` arrives unchanged, the frame counter travels
in ``ImageShare.frame``, and ``FecFrameInfo`` is a ``FrameInfo`` (so a ``MessageInfo``: seq is the
user's header.seq) with ``shares_received``/``shares_needed``/``shares_sent``; a FEC frame is
whole or not shown, so ``complete`` always, ``patched`` never, ``fresh_fraction`` 1. The shares
are filed and a frame's JPEG rebuilt on the executor (no pixels); it is decoded when looked at.
"""
from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..jpeg import decode_jpeg, encode_jpeg
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
    LatestFrame,
    SentFrame,
    check_quality,
    frame_array,
    frames_skipped,
    publish_paced,
    sample_stamps,
)

DEFAULT_SHARE_BYTES = 1100    # one UDP datagram with Zenoh's headers at a 1500-byte MTU
MAX_SHARES = 256              # zfec's limit on n
MAX_SHARE_BYTES = 64 << 10    # receive-side bound, checked before anything is stored
MAX_JPEG_BYTES = 16 << 20
MAX_SIDE = 16384
LOSS_WINDOW_FRAMES = 60       # frames over which the receiver measures share loss


@message(name="zenoh_robot/ImageShare")
class ImageShare(Message):
    header: Header = None  # type: ignore[assignment]    # the user's Image header, unchanged
    frame: int = ros_field("uint64", default=0)     # the transport's frame counter (reassembly, latest-frame)
    index: int = ros_field("uint16", default=0)     # share number: < k data, >= k parity
    k: int = ros_field("uint16", default=0)         # shares needed to rebuild the frame
    n: int = ros_field("uint16", default=0)         # shares sent for the frame
    size: int = ros_field("uint32", default=0)      # bytes of the frame's JPEG (the last data share is padded)
    height: int = ros_field("uint32", default=0)
    width: int = ros_field("uint32", default=0)
    encoding: str = "rgb8"                  # of the decoded frame: rgb8 or mono8
    data: bytes = b""

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@dataclass(slots=True)
class FecFrameInfo(FrameInfo):
    """What the viewer is shown: a FEC frame is whole or not delivered, so always fully fresh."""
    shares_received: int = 0      # when the frame was rebuilt (== shares_needed)
    shares_needed: int = 0         # k
    shares_sent: int = 0           # n

    @property
    def k(self) -> int:
        return self.shares_needed

    @property
    def n(self) -> int:
        return self.shares_sent


def shares_for(k: int, loss: float, target: float = 0.99, max_expansion: float = 3.0) -> int:
    """Smallest n >= k with P(at least k of n arrive) >= ``target`` at independent loss ``loss``,
    clamped to ceil(max_expansion * k) and MAX_SHARES."""
    if not 1 <= k <= MAX_SHARES:
        raise ValueError(f"k must be 1..{MAX_SHARES}, got {k}")
    p = min(max(float(loss), 0.0), 0.99)
    ceiling = max(k, min(MAX_SHARES, math.ceil(max_expansion * k)))
    if p == 0.0:
        return min(ceiling, k + 1) if k < ceiling else k   # one spare share: loss is rarely exactly 0
    q = 1.0 - p
    for n in range(k, ceiling + 1):
        # P(X >= k), X ~ Binomial(n, q): sum of the upper tail.
        tail = sum(math.comb(n, i) * q ** i * p ** (n - i) for i in range(k, n + 1))
        if tail >= target:
            return n
    return ceiling


def split(blob: bytes, share_bytes: int, loss: float, target: float = 0.99,
          max_expansion: float = 3.0) -> tuple[int, int, list[bytes]]:
    """``blob`` as (k, n, n shares); any k of them rebuild it (:func:`join`)."""
    import zfec  # the [image] extra

    k = max(1, min(MAX_SHARES - 1, math.ceil(len(blob) / share_bytes)))
    size = math.ceil(len(blob) / k)
    padded = blob + bytes(k * size - len(blob))
    blocks = [padded[i * size:(i + 1) * size] for i in range(k)]
    n = shares_for(k, loss, target, max_expansion)
    if n == k:
        return k, n, blocks
    return k, n, [bytes(b) for b in zfec.Encoder(k, n).encode(blocks)]


def join(k: int, n: int, size: int, shares: dict[int, bytes]) -> bytes:
    """The blob back from any ``k`` shares (index -> bytes) of the ``n``; ValueError if fewer."""
    import zfec

    if len(shares) < k:
        raise ValueError(f"{len(shares)} of {k} shares")
    if all(i in shares for i in range(k)):      # every data share: no decoding needed
        blob = b"".join(shares[i] for i in range(k))
    else:
        nums = sorted(shares)[:k]
        blob = b"".join(zfec.Decoder(k, n).decode([shares[i] for i in nums], nums))
    return blob[:size]


class FecImagePublisher(ImageSender):
    """Publishes frames as one JPEG each, in k shares + parity sized from the loss."""

    follows_loss = True   # parity is sized from set_loss's figure

    def __init__(self, node: Any, topic: str, qos: QoSProfile = IMAGE, *, quality: int = 70,
                 share_bytes: int = DEFAULT_SHARE_BYTES, loss: float = 0.1, target: float = 0.99,
                 max_expansion: float = 3.0, pace_s: float = 0.0015) -> None:
        check_quality(quality)
        if not 64 <= share_bytes <= MAX_SHARE_BYTES:
            raise ValueError(f"share_bytes must be 64..{MAX_SHARE_BYTES}")
        self.quality = quality
        self.share_bytes = share_bytes
        self.target = target
        self.max_expansion = max_expansion
        self.loss = loss
        # As ImagePublisher: a frame is a burst; BLOCK makes the camera wait instead of Zenoh dropping
        # most of it, and pacing past Zenoh's 1 ms batching window keeps each share in its own datagram
        # (a batch lost whole would take several shares with it: correlated loss defeats the parity).
        self.publisher = node.create_publisher(ImageShare, topic, qos.replace(history="keep_all", depth=0))
        self.pace_s = pace_s
        self.frames = 0
        self.last_k = 0
        self.last_n = 0
        self.shares_sent = 0

    def publish(self, frame: Image | np.ndarray, header: Header | None = None) -> int:
        """Send one frame; returns its frame number (the shares' ``frame``)."""
        return self.send(frame, header).frame

    def send(self, frame: Image | np.ndarray, header: Header | None = None) -> SentFrame:
        shares = self.encode(frame, header)
        publish_paced(self.publisher, shares, self.pace_s)
        self.shares_sent += len(shares)
        self.frames += 1
        n = shares[0].frame
        # A frame is whole or absent: one piece a frame, numbered as a sliced frame's first strip.
        return SentFrame(n, shares[0].header.stamp, (n * MAX_SLICES,))

    def encode(self, frame: Image | np.ndarray, header: Header | None = None) -> list[ImageShare]:
        arr, header = frame_array(frame, header, "FecImagePublisher")
        h, w = arr.shape[:2]
        blob = encode_jpeg(arr, self.quality)
        k, n, parts = split(blob, self.share_bytes, self.loss, self.target, self.max_expansion)
        self.last_k, self.last_n = k, n
        head = header if header is not None else Header(time.time_ns(), "", self.frames)   # as ImagePublisher
        enc = "mono8" if arr.ndim == 2 else "rgb8"
        return [ImageShare(head, self.frames, i, k, n, len(blob), h, w, enc, part) for i, part in enumerate(parts)]


@dataclass(slots=True)
class RebuiltFrame:
    jpeg: bytes
    height: int
    width: int
    encoding: str
    stamp: int                # the user's header.stamp
    info: FecFrameInfo
    header: Header = None  # type: ignore[assignment]    # the user's header, unchanged


class FecAssembler:
    """Shares in, whole frames out (latest-frame semantics); no Zenoh, no decoding of pixels.

    Bounded: holds the shares of one frame (at most n <= 256 of at most MAX_SHARE_BYTES each,
    all of one size); a share that cannot belong to any frame is counted and dropped first.
    Measures share loss over the last LOSS_WINDOW_FRAMES frames (:attr:`loss`), frames that
    sent nothing at all included, for the publisher's feedback.
    """

    def __init__(self) -> None:
        self._shares: dict[int, bytes] = {}
        self._first: ImageShare | None = None
        self._source_ns = 0               # the current frame's first share: its publication stamp
        self._publisher_id = 0
        self._done = True
        self._seen = 0                    # shares of the current frame seen, rebuilt or not
        self._window: deque[tuple[int, int]] = deque(maxlen=LOSS_WINDOW_FRAMES)   # (seen, sent)
        self._order = LatestFrame()
        self.frames_rebuilt = 0
        self.frames_seen = 0              # frames of which at least one share arrived
        self.frames_missed = 0            # frame numbers skipped entirely
        self.bad_shares = 0
        self.stale_shares = 0
        self.decode_errors = 0

    @staticmethod
    def share_error(s: ImageShare) -> str | None:
        if s.encoding not in ("rgb8", "mono8"):
            return f"encoding {s.encoding!r}"
        if not (1 <= s.k <= s.n <= MAX_SHARES and 0 <= s.index < s.n):
            return f"share {s.index} of k={s.k} n={s.n}"
        if not (1 <= s.width <= MAX_SIDE and 1 <= s.height <= MAX_SIDE):
            return f"frame of {s.width}x{s.height}"
        if not (1 <= len(s.data) <= MAX_SHARE_BYTES and 1 <= s.size <= min(MAX_JPEG_BYTES, s.k * len(s.data))
                and s.size > (s.k - 1) * len(s.data)):
            return f"{len(s.data)}-byte share of a {s.size}-byte frame in {s.k}"
        return None

    @property
    def loss(self) -> float:
        """Share loss measured over the recent frames (0..1; NaN before any)."""
        sent = sum(n for _, n in self._window)
        return 1.0 - sum(s for s, _ in self._window) / sent if sent else math.nan

    def add(self, s: ImageShare, now_ns: int | None = None, info: Any = None) -> RebuiltFrame | None:
        """File one share; the frame it completes (once, at its k-th share), else None.

        ``info``: the share's MessageInfo, when there is one (publisher id, publication stamp)."""
        if self.share_error(s) is not None:
            self.bad_shares += 1
            return None
        frame = s.frame
        if self._order.is_stale(frame):
            self.stale_shares += 1
            return None
        if frame != self._order.frame:
            self._close(frame)
            self._order.begin(frame)
            self._first, self._shares, self._done, self._seen = s, {}, False, 0
            publisher_id, source, _ = sample_stamps(info)
            self._source_ns, self._publisher_id = source or s.header.stamp, publisher_id
            self.frames_seen += 1
        first = self._first
        assert first is not None
        if (s.k, s.n, s.size, len(s.data), s.height, s.width, s.encoding) != (
                first.k, first.n, first.size, len(first.data), first.height, first.width, first.encoding):
            self.bad_shares += 1     # disagrees with the frame's first share
            return None
        if s.index in self._shares:
            return None              # a duplicate
        self._seen += 1
        if self._done:
            return None              # already rebuilt: counted for the loss figure only
        self._shares[s.index] = s.data
        if len(self._shares) < s.k:
            return None
        self._done = True
        try:
            jpeg = join(s.k, s.n, s.size, self._shares)
        except Exception:
            self.decode_errors += 1
            return None
        finally:
            self._shares = {}        # keep only counts once rebuilt
        self.frames_rebuilt += 1
        now_ns = now_ns or time.time_ns()
        head = first.header
        got = FecFrameInfo(self._publisher_id, head.seq, self._source_ns, now_ns, IMAGE_TYPE, frame=frame,
                           slices_received=1, slice_count=1, oldest_stamp_ns=self._source_ns,
                           shares_received=s.k, shares_needed=s.k, shares_sent=s.n)
        return RebuiltFrame(jpeg, s.height, s.width, s.encoding, head.stamp, got, head)

    def _close(self, next_frame: int) -> None:
        """The current frame is over: file its share counts, and whole frames skipped."""
        if self._first is not None:
            n = self._first.n
            self._window.append((self._seen, n))
            skipped = next_frame - self._order.frame - 1
            if 0 < skipped <= LOSS_WINDOW_FRAMES:   # a forged jump must not flood the window
                self.frames_missed += skipped
                self._window.extend([(0, n)] * skipped)


class FecReceiver(ImageReceiver):
    """Shares in; shows the newest frame rebuilt (its JPEG, as sent), decoded when looked at."""

    message_type = ImageShare
    burst = 512     # a frame's shares and parity come in a burst: the queue holds a frame's worth

    def __init__(self, node: Any = None, topic: str = "", qos: QoSProfile = IMAGE, *,
                 records: FrameRecords | None = None,
                 callback: Callable[[Image, FrameInfo], None] | None = None,
                 topic_statistics: Any = None) -> None:
        self.assembler = FecAssembler()
        self._last_shown = -1
        super().__init__(node, topic, qos, records=records, callback=callback, topic_statistics=topic_statistics)

    def _file(self, s: ImageShare, info: Any) -> None:
        _, _, received = sample_stamps(info)
        got = self.assembler.add(s, received, info)   # the assembler applies the stale rule
        if got is None:
            return
        frame = got.info.frame
        # A rebuilt frame is whole and fresh: one "strip" a frame; the frames between the last one
        # shown and this one, seen or not, were never shown.
        self.strips_expected += frames_skipped(self._last_shown, frame) + 1
        self.strips_fresh += 1
        self.complete += 1
        self._last_shown = frame
        self._begin(frame, got.stamp, received, got.info.age_ms)
        self.records.whole(frame, got.stamp, received)
        self.records.piece(frame * MAX_SLICES, got.stamp, received)
        self._show(got, got.info, got.header)

    def _decode(self, got: RebuiltFrame) -> np.ndarray | None:
        try:
            arr = decode_jpeg(got.jpeg, max_width=got.width, max_height=got.height)
            if arr.shape[:2] != (got.height, got.width) or (arr.ndim == 2) != (got.encoding == "mono8"):
                raise ValueError(f"JPEG of {arr.shape} in a {got.width}x{got.height} {got.encoding} frame")
        except Exception:   # a damaged or hostile JPEG: counted, never raised into the viewer
            self.assembler.decode_errors += 1
            return None
        return arr


class FecImageSubscription(FecReceiver):
    """``callback(Image, FecFrameInfo)`` with every frame rebuilt, decoded on the executor (as an
    rclpy subscription); a viewer that shows the newest frame wants :class:`FecReceiver` instead."""

    def __init__(self, node: Any, topic: str, callback: Callable[[Image, FecFrameInfo], None],
                 qos: QoSProfile = IMAGE) -> None:
        # The info a FecReceiver gives is always a FecFrameInfo.
        super().__init__(node, topic, qos, callback=callback)   # type: ignore[arg-type]
