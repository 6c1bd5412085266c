"""Camera frames on the GCS without starving setpoints and telemetry.

Decoding a 320x240 frame's JPEG slices costs milliseconds; on the executor that also
serves setpoints and sensor data it made the GCS drop 90 % of its sensor samples at five
drones. So the executor only files each slice away (a dict insert, counted and stamped
for the image stream's figures) and a frame is decoded only when someone looks at it:
``FrameKeeper.latest()``, called from a saver or viewer thread, never from the executor.

Bounded: one frame being filled and the last finished one, at most ``MAX_SLICES`` slices
each; a slice that cannot belong to any frame is counted and dropped before it is stored.
A missing strip is patched with the same strip of the frame decoded before (as the
library's ``ImageSubscription`` does), with the same limits checked before allocating.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from zenoh_robot.image_transport import (
    MAX_FRAME_BYTES,
    MAX_SIDE,
    MAX_SLICE_BYTES,
    MAX_SLICES,
    FrameInfo,
    ImageSlice,
    decode_strip,
)
from zenoh_robot.msgs import Image


class FrameKeeper:
    """Per drone: slices of the newest frames, decoded on demand (see the module doc)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._filling: dict[int, ImageSlice] = {}
        self._filling_frame = -1
        self._filling_count = 0
        self._done: list[ImageSlice] = []     # the last frame whose next one has begun (or complete)
        self._done_frame = -1
        self._decoded_frame = -1
        self._array: np.ndarray | None = None
        self._info: FrameInfo | None = None
        self.frames = 0          # frames begun (first slice seen)
        self.complete = 0        # frames whose every slice arrived
        self.bad_slices = 0
        self.late_slices = 0
        self.decoded = 0
        self.decode_s = 0.0      # CPU-side time spent decoding (the cost now off the executor)
        self._raw: tuple[Image, FrameInfo] | None = None   # raw/jpeg modes: one Image per frame

    # -- executor: cheap -------------------------------------------------------------
    def add(self, s: ImageSlice) -> bool:
        """File one slice; True when it begins a new frame (for the stream's counts)."""
        if not (1 <= s.count <= MAX_SLICES and 0 <= s.index < s.count and len(s.data) <= MAX_SLICE_BYTES):
            self.bad_slices += 1
            return False
        frame = s.header.seq
        with self._lock:
            if frame < self._filling_frame and self._filling_frame - frame < 1000:
                self.late_slices += 1     # older than the frame being filled: latest-frame semantics
                return False
            new = frame != self._filling_frame
            if new:
                if self._filling:
                    self._done, self._done_frame = list(self._filling.values()), self._filling_frame
                self._filling, self._filling_frame, self._filling_count = {}, frame, s.count
                self.frames += 1
            if s.count == self._filling_count:
                self._filling[s.index] = s
                if len(self._filling) == s.count:
                    self.complete += 1
                    self._done, self._done_frame = list(self._filling.values()), frame
            else:
                self.bad_slices += 1
            return new

    def add_image(self, img: Image, info: FrameInfo) -> None:
        """A whole frame in one message (raw rgb8 or JPEG): kept as it came, converted on demand."""
        with self._lock:
            self._raw = (img, info)
            self.frames += 1
            self.complete += 1

    # -- any other thread ------------------------------------------------------------
    def latest(self) -> tuple[np.ndarray, FrameInfo] | None:
        """The newest finished frame as an array (decoded now, once per frame), or None."""
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
        with self._lock:
            slices, frame = self._done, self._done_frame
        if not slices:
            return None
        if frame != self._decoded_frame:
            t0 = time.process_time()
            self._decode(slices, frame)
            self.decode_s += time.process_time() - t0
            self._decoded_frame = frame
        if self._array is None or self._info is None:
            return None
        return self._array, self._info

    def _decode(self, slices: list[ImageSlice], frame: int) -> None:
        first = slices[0]
        channels = 1 if first.encoding == "mono8" else 3
        w, h = first.width, first.height
        if first.encoding not in ("rgb8", "mono8") or not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE
                                                           and w * h * channels <= MAX_FRAME_BYTES):
            self.bad_slices += len(slices)
            return
        shape = (first.height, first.width) if channels == 1 else (first.height, first.width, channels)
        prev = self._array
        canvas = prev.copy() if prev is not None and prev.shape == shape else np.zeros(shape, dtype=np.uint8)
        got = 0
        for s in slices:
            if (s.width, s.height, s.encoding) != (w, h, first.encoding) or not 0 <= s.row < s.height:
                self.bad_slices += 1
                continue
            try:
                strip = decode_strip(s.data, max_width=s.width, max_height=s.height - s.row)
                if strip.ndim == 2 and channels == 3:
                    strip = np.repeat(strip[:, :, None], 3, axis=2)
                if strip.ndim != canvas.ndim or (strip.ndim == 3 and strip.shape[2] != channels):
                    raise ValueError(f"strip of shape {strip.shape} in a {s.encoding} frame")
                canvas[s.row:s.row + strip.shape[0], :strip.shape[1]] = strip
                got += 1
            except Exception:   # a hostile or damaged strip: counted, the rest of the frame still shown
                self.bad_slices += 1
        if got:
            age = (time.time_ns() - first.header.stamp) / 1e6 if first.header.stamp else float("nan")
            self._array, self._info = canvas, FrameInfo(frame, got, first.count, age)
            self.decoded += 1
