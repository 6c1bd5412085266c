"""Camera frames on the GCS without starving setpoints and telemetry.

Decoding a 320x240 frame's JPEG slices costs milliseconds; on the executor that also
serves setpoints and sensor data it made the GCS drop 90 % of its sensor samples at five
drones. So the executor only files each slice away (a dict insert, counted and stamped
for the image stream's figures) and a frame is decoded only when someone looks at it:
``FrameKeeper.latest()``, called from a saver or viewer thread, never from the executor.

What is shown is the newest strip received at each strip index when the last frame closed
(its next one began, or its last strip arrived), as the library's ``ImageSubscription``
patches a lost strip with the same strip of an older frame; strips already decoded are not
decoded again. The figures say how honest the picture is (``FrameInfo``): whole fresh
frames, the fraction of strips that arrived (frames skipped entirely included) and the age
of the oldest strip in the picture, all kept without decoding anything.

Bounded: the strips of one geometry, at most ``MAX_SLICES`` of at most ``MAX_SLICE_BYTES``;
a slice that cannot belong to any frame is counted and dropped before it is stored.
"""
from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from zenoh_robot.image_transport import IMAGE_TYPE, FrameInfo, ImageSlice, ImageSubscription, decode_strip
from zenoh_robot.msgs import Image

MAX_GAP_FRAMES = 1000    # a jump in frame numbers beyond this is a restart or a forgery, not loss


class FrameKeeper:
    """Per drone: the newest strips, decoded on demand (see the module doc)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._decode_lock = threading.Lock()
        # Executor side, under _lock.
        self._strips: dict[int, tuple[ImageSlice, int]] = {}   # index -> (newest slice, its publication ns)
        self._geometry: tuple[int, int, int, str] | None = None  # count, width, height, encoding
        self._frame = -1
        self._got: set[int] = set()
        self._closed = True
        self._head: ImageSlice | None = None
        self._source_ns = 0
        self._received_ns = 0
        self._publisher_id = 0
        self._shown: dict[int, tuple[ImageSlice, int]] = {}
        self._shown_serial = 0
        self._raw: tuple[Image, FrameInfo] | None = None   # raw/jpeg/fec modes: one Image per frame
        self.last_info: FrameInfo | None = None             # the newest frame closed (figures, no pixels)
        # Decoder side, under _decode_lock.
        self._decoded_serial = 0
        self._drawn: dict[int, tuple[int, int]] = {}   # index -> (frame, publication ns) of the strip drawn
        self._drawn_count = 0
        self._array: np.ndarray | None = None
        self._info: FrameInfo | None = None
        self.frames = 0          # frames begun (first slice seen)
        self.complete = 0        # frames whose every slice arrived
        self.patched = 0         # frames shown with strips of older frames
        self.strips_fresh = 0    # strips received, of frames closed (FEC, raw: whole frames)
        self.strips_expected = 0  # strips of the frames closed and of those skipped entirely
        self.bad_slices = 0
        self.late_slices = 0
        self.decoded = 0
        self.decode_s = 0.0      # CPU-side time spent decoding (the cost now off the executor)

    # -- executor: cheap -------------------------------------------------------------
    def add(self, s: ImageSlice, info: Any = None) -> bool:
        """File one slice (``info``: its MessageInfo); True when it begins a new frame."""
        if ImageSubscription._slice_error(s) is not None:
            self.bad_slices += 1
            return False
        frame = s.frame
        received = int(getattr(info, "received_stamp_ns", 0)) or time.time_ns()
        with self._lock:
            if frame < self._frame and self._frame - frame < MAX_GAP_FRAMES:
                self.late_slices += 1     # older than the frame being filled: latest-frame semantics
                return False
            new = frame != self._frame
            if new:
                if not self._closed:
                    self._close()
                geometry = (s.count, s.width, s.height, s.encoding)
                if geometry != self._geometry:
                    self._strips, self._geometry = {}, geometry
                skipped = frame - self._frame - 1 if self._frame >= 0 else 0
                if 0 < skipped < MAX_GAP_FRAMES:
                    self.strips_expected += skipped * s.count
                self._frame, self._got, self._closed, self._head = frame, set(), False, s
                self._source_ns = int(getattr(info, "source_stamp_ns", 0)) or s.header.stamp
                self._publisher_id = int(getattr(info, "publisher_id", 0))
                self.frames += 1
            elif (s.count, s.width, s.height, s.encoding) != self._geometry:
                self.bad_slices += 1      # disagrees with the frame's first slice
                return False
            if s.index in self._got:
                return new                # a duplicate
            self._got.add(s.index)
            self._strips[s.index] = (s, self._source_ns)
            self._received_ns = received
            if len(self._got) == s.count and not self._closed:
                self.complete += 1
                self._close()
            return new

    def _close(self) -> None:
        """The frame being filled is over: what the viewer shows from now on (a dict copy, no pixels)."""
        head = self._head
        assert head is not None and self._geometry is not None
        self._closed = True
        count = self._geometry[0]
        # Counted when a frame closes, so the figures never see a frame half-filled.
        self.strips_fresh += len(self._got)
        self.strips_expected += count
        self._shown = dict(self._strips)
        self._shown_serial += 1
        stamps = [t for _, t in self._shown.values() if t]
        info = FrameInfo(self._publisher_id, head.header.seq, self._source_ns, self._received_ns, IMAGE_TYPE,
                         frame=self._frame, slices_received=len(self._got), slice_count=count,
                         oldest_stamp_ns=min(stamps, default=0), patched=len(self._shown) > len(self._got))
        self.patched += info.patched
        self.last_info = info

    def add_image(self, img: Image, info: FrameInfo) -> None:
        """A whole frame in one message (raw rgb8, JPEG, rebuilt FEC): kept as it came, converted on demand."""
        with self._lock:
            skipped = info.frame - self._frame - 1 if self._frame >= 0 else 0
            if 0 < skipped < MAX_GAP_FRAMES:
                self.strips_expected += skipped
            self._frame = max(self._frame, info.frame)
            self._raw = (img, info)
            self.last_info = info
            self.frames += 1
            self.complete += 1
            self.strips_fresh += 1
            self.strips_expected += 1

    # -- figures (any thread, no decoding) -------------------------------------------
    @property
    def oldest_strip_age_ms(self) -> float:
        """Of the newest frame closed: delivery - publication of its oldest strip (NaN before any)."""
        info = self.last_info
        return float("nan") if info is None else info.oldest_strip_age_ms

    # -- any other thread ------------------------------------------------------------
    def latest(self) -> tuple[np.ndarray, FrameInfo] | None:
        """The newest finished frame as an array (decoded now, new strips only), or None."""
        with self._lock:
            raw = self._raw
        if raw is not None:
            t0 = time.process_time()
            try:
                arr = raw[0].to_array()
            except Exception:   # a malformed image: counted, never raised into the viewer
                self.bad_slices += 1
                return None
            self.decode_s += time.process_time() - t0
            self.decoded += 1
            return arr, raw[1]
        with self._decode_lock:
            with self._lock:
                shown, serial, info = self._shown, self._shown_serial, self.last_info
            if not shown or info is None:
                return None
            if serial != self._decoded_serial:
                t0 = time.process_time()
                self._decode(shown, info)
                self.decode_s += time.process_time() - t0
                self._decoded_serial = serial
            if self._array is None or self._info is None:
                return None
            return self._array.copy(), self._info

    def _decode(self, shown: dict[int, tuple[ImageSlice, int]], info: FrameInfo) -> None:
        first = next(iter(shown.values()))[0]
        channels = 1 if first.encoding == "mono8" else 3
        shape = (first.height, first.width) if channels == 1 else (first.height, first.width, channels)
        if self._array is None or self._array.shape != shape or first.count != self._drawn_count:
            self._array, self._drawn, self._drawn_count = np.zeros(shape, dtype=np.uint8), {}, first.count
        canvas = self._array
        for index, (s, stamp) in shown.items():
            if self._drawn.get(index) == (s.frame, stamp):
                continue                  # this strip is on the canvas already
            try:
                strip = decode_strip(s.data, max_width=s.width, max_height=s.height - s.row)
                if strip.ndim == 2 and channels == 3:
                    strip = np.repeat(strip[:, :, None], 3, axis=2)
                if strip.ndim != canvas.ndim or (strip.ndim == 3 and strip.shape[2] != channels):
                    raise ValueError(f"strip of shape {strip.shape} in a {s.encoding} frame")
                canvas[s.row:s.row + strip.shape[0], :strip.shape[1]] = strip
                self._drawn[index] = (s.frame, stamp)
            except Exception:   # a hostile or damaged strip: counted, the rest of the frame still shown
                self.bad_slices += 1
        self._info = info
        self.decoded += 1
