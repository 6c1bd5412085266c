"""What every image mode shares: the frame's info, the one stale-frame rule, the sender and receiver.

A receiver works in two halves. On the executor that also serves setpoints and sensors it only
*files* each sample (a dict insert, a few comparisons, counted and stamped for the stream's
figures); a frame is decoded only when someone asks for it (:meth:`ImageReceiver.latest`), on the
asking thread, and once per frame however often it is asked. Decoding a 320x240 frame costs
milliseconds: done per sample on the executor, it made a five-drone GCS drop 90 % of its sensor
samples. A receiver given a ``callback`` decodes every frame as it closes instead, on the
executor, as an rclpy subscription would (a viewer that wants every frame, not the newest).
"""
from __future__ import annotations

import math
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..message import Message
from ..msgs import Header, Image
from ..qos import IMAGE, QoSProfile
from ..subscription import MessageInfo

IMAGE_TYPE = "sensor_msgs/Image"
# The most pieces a frame may be cut into, and so the stride of piece numbers: piece ``index`` of
# frame ``f`` is numbered f * MAX_SLICES + index by the sender's and the receiver's records alike.
MAX_SLICES = 4096
STALE_FRAMES_TO_RESTART = 2   # older frames in a row, each newer than the last: the stream restarted
MAX_GAP_FRAMES = 1000         # a jump in frame numbers beyond this is a restart or a forgery, not loss


@dataclass(slots=True)
class FrameInfo(MessageInfo):
    """A frame shown: MessageInfo's fields (``seq`` is the user's header.seq) and how fresh it is.

    ``source_stamp_ns`` is when the frame's first piece was published (the envelope's stamp; the
    header's stamp when fed without one), ``received_stamp_ns`` when its last piece was filed.
    """
    frame: int = 0                 # the transport's frame counter (the pieces' ``frame``; raw, jpeg: seq)
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


def frames_skipped(previous: int, frame: int) -> int:
    """Frames between ``previous`` and ``frame`` that never showed up; 0 on a restart, before the
    first frame, or for a jump so large it is a restart or a forgery (it must not read as loss)."""
    skipped = frame - previous - 1
    return skipped if previous >= 0 and 0 < skipped < MAX_GAP_FRAMES else 0


class LatestFrame:
    """The stale-frame rule of every receiver: the newest frame wins.

    A piece of a frame older than the current one is stale (late, or reordered) and dropped. But
    older frames that keep coming, each newer than the one before, are the live stream: the
    publisher restarted, or the current frame number was forged far ahead. After
    STALE_FRAMES_TO_RESTART of them the receiver follows, so a forged number cannot blind it longer.
    """

    def __init__(self) -> None:
        self.frame = -1            # the current frame (-1: none yet)
        self._stale_run = 0        # distinct older frames seen in a row since the current one began
        self._stale_last = -1

    def is_stale(self, frame: int) -> bool:
        if frame >= self.frame:
            return False
        if frame > self._stale_last:
            self._stale_run += 1
            self._stale_last = frame
        return self._stale_run < STALE_FRAMES_TO_RESTART

    def begin(self, frame: int) -> int:
        """``frame`` is the current one from now on; returns the frames skipped (:func:`frames_skipped`)."""
        skipped = frames_skipped(self.frame, frame)
        self.frame = frame
        self._stale_run, self._stale_last = 0, -1
        return skipped


Record = Callable[[int, int, int], None]    # (number, stamp ns, received ns): StreamRecorder.record


def _ignore(number: int, stamp_ns: int, received_ns: int) -> None:
    pass


@dataclass(frozen=True, slots=True)
class FrameRecords:
    """Where a receiver reports what arrived, for the stream's figures, numbered and stamped as the
    sender's :class:`SentFrame` says what it sent (so the two records pair up)."""
    frame: Record = _ignore    # a frame begun (sliced) or arrived (raw, jpeg, fec)
    whole: Record = _ignore    # every piece of a frame arrived (sliced, fec)
    piece: Record = _ignore    # a piece arrived, late ones too: frame * MAX_SLICES + index (fec: one a frame)


@dataclass(frozen=True, slots=True)
class SentFrame:
    """What a sender put on the wire for one frame, as the receivers' :class:`FrameRecords` number it."""
    frame: int                     # the pieces' frame counter (raw, jpeg: the message's sequence number)
    stamp_ns: int                  # the header's stamp (raw, jpeg: the publication stamp)
    pieces: tuple[int, ...] = ()   # frame * MAX_SLICES + index of each piece (raw, jpeg: none)


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


def check_quality(quality: int) -> int:
    if not 1 <= quality <= 95:
        raise ValueError(f"JPEG quality must be 1..95, got {quality}")
    return quality


def publish_paced(publisher: Any, pieces: list[Any], pace_s: float) -> None:
    """Publish a frame's pieces ``pace_s`` apart, past Zenoh's batching window (see ImagePublisher)."""
    for i, piece in enumerate(pieces):
        if i and pace_s:
            time.sleep(pace_s)
        publisher.publish(piece)


class ImageSender(ABC):
    """A mode's publisher (the registry's ``image_publisher``): ``send`` one frame, say what went out."""

    publisher: Any                          # the underlying Publisher (counts, events)
    follows_loss: ClassVar[bool] = False    # the mode sizes its redundancy from ``loss``
    loss = 0.0                              # 0..1 (set_loss)

    @abstractmethod
    def send(self, frame: Image | np.ndarray, header: Header | None = None) -> SentFrame:
        """Send one frame (HxW or HxWx3 uint8, or an Image); ``header`` goes out as given."""

    def set_loss(self, loss: float) -> None:
        """The packet loss the link shows (0..1): a configured value or the receiver's feedback."""
        self.loss = min(max(float(loss), 0.0), 0.99)

    def get_subscription_count(self) -> int:
        """Subscriptions matched (as rclpy's Publisher.get_subscription_count)."""
        return int(self.publisher.get_subscription_count())


@dataclass(slots=True)
class _Shown:
    serial: int
    payload: Any          # the mode's own: newest strips, a rebuilt JPEG, an Image
    info: FrameInfo
    header: Header        # the user's, unchanged


def sample_stamps(info: Any) -> tuple[int, int, int]:
    """(publisher id, publication ns, reception ns) from a sample's MessageInfo; 0 where it says
    nothing (a sample fed by hand), and reception now."""
    return (int(getattr(info, "publisher_id", 0)), int(getattr(info, "source_stamp_ns", 0)),
            int(getattr(info, "received_stamp_ns", 0)) or time.time_ns())


def stamp_age_ms(source_ns: int, received_ns: int) -> float:
    return (received_ns - source_ns) / 1e6 if source_ns else math.nan


class ImageReceiver(ABC):
    """A mode's receiver (the registry's ``image_receiver``): files samples, decodes on demand.

    Without a node it is fed by hand (:meth:`add`). Counters, for figures that decode nothing:
    ``frames`` (begun: sliced; arrived: the others), ``complete`` (whole and fresh), ``patched``, ``strips_fresh`` of
    ``strips_expected`` (frames skipped entirely included; whole-frame modes count frames),
    ``last_info`` (the newest frame shown), ``last_age_ms`` (of the newest frame when it began),
    ``decoded`` and ``decode_s`` (CPU time spent decoding, on the threads that asked).
    """

    message_type: ClassVar[type[Message]]
    burst: ClassVar[int] = 0       # samples one frame arrives as: the subscription's queue holds them

    def __init__(self, node: Any = None, topic: str = "", qos: QoSProfile = IMAGE, *,
                 records: FrameRecords | None = None,
                 callback: Callable[[Image, FrameInfo], None] | None = None,
                 topic_statistics: Any = None) -> None:
        self.records = records or FrameRecords()
        self.callback = callback
        self._order = LatestFrame()
        self._lock = threading.Lock()          # the executor files, any thread reads
        self._decode_lock = threading.Lock()   # one decoder at a time: a mode may draw on one canvas
        self._shown: _Shown | None = None
        self._pending: list[_Shown] = []       # shown, not yet given to the callback
        self._serial = 0
        self._decoded_serial = 0
        self._array: np.ndarray | None = None
        self.last_info: FrameInfo | None = None
        self.last_age_ms = math.nan
        self.frames = 0
        self.complete = 0
        self.patched = 0
        self.strips_fresh = 0
        self.strips_expected = 0
        self.decoded = 0
        self.decode_s = 0.0
        self.subscription: Any = None
        if node is not None:
            if qos.depth < self.burst:
                qos = qos.replace(depth=self.burst)
            # Two required arguments: the subscription passes each sample's MessageInfo (publisher, stamps).
            self.subscription = node.create_subscription(self.message_type, topic,
                                                         lambda msg, info: self.add(msg, info), qos,
                                                         topic_statistics=topic_statistics)

    # -- the executor: cheap ---------------------------------------------------------
    def add(self, msg: Any, info: Any = None) -> None:
        """File one sample (``info``: its MessageInfo, when there is one). Nothing is decoded
        here unless a ``callback`` wants every frame."""
        with self._lock:
            self._file(msg, info)
            pending, self._pending = self._pending, []
        for shown in pending:
            got = self._image_of(shown)
            if got is not None and self.callback is not None:
                self.callback(*got)

    @abstractmethod
    def _file(self, msg: Any, info: Any) -> None:
        """The mode's filing, under the lock: validate, apply the stale rule, count, :meth:`_show`."""

    def _begin(self, number: int, stamp_ns: int, received_ns: int, age_ms: float) -> None:
        self.frames += 1
        self.last_age_ms = age_ms
        self.records.frame(number, stamp_ns, received_ns)

    def _show(self, payload: Any, info: FrameInfo, header: Header) -> None:
        """The frame just closed is what the viewer sees from now on (a reference: nothing decoded)."""
        self._serial += 1
        self._shown = _Shown(self._serial, payload, info, header)
        self.last_info = info
        self.patched += info.patched
        if self.callback is not None:
            self._pending.append(self._shown)

    # -- figures (any thread, no decoding) -------------------------------------------
    @property
    def oldest_strip_age_ms(self) -> float:
        """Of the newest frame shown: delivery - publication of its oldest strip (NaN before any)."""
        info = self.last_info
        return math.nan if info is None else info.oldest_strip_age_ms

    # -- any thread: decoding --------------------------------------------------------
    def latest(self) -> tuple[np.ndarray, FrameInfo] | None:
        """The newest frame shown, as an array, decoded now on the caller's thread (once per
        frame), or None (nothing yet, or it cannot be decoded: counted by the mode)."""
        with self._lock:
            shown = self._shown
        if shown is None:
            return None
        arr = self._array_of(shown)
        return None if arr is None else (arr.copy(), shown.info)

    def _image_of(self, shown: _Shown) -> tuple[Image, FrameInfo] | None:
        arr = self._array_of(shown)
        if arr is None:
            return None
        head = shown.header
        return Image.from_array(arr, header=Header(head.stamp, head.frame_id, head.seq)), shown.info

    def _array_of(self, shown: _Shown) -> np.ndarray | None:
        with self._decode_lock:
            if self._decoded_serial != shown.serial:
                t0 = time.process_time()
                self._array = self._decode(shown.payload)
                self.decode_s += time.process_time() - t0
                self.decoded += 1
                self._decoded_serial = shown.serial
            return self._array

    @abstractmethod
    def _decode(self, payload: Any) -> np.ndarray | None:
        """The shown frame's pixels (None if they cannot be had: count why); under the decode lock.
        The array may be kept and drawn on again: callers get copies."""
