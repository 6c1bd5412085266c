"""Camera sources for the companion: a synthetic moving test pattern, or OpenCV when present."""
from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class FrameSource(Protocol):
    width: int
    height: int

    def read(self) -> np.ndarray | None: ...
    def close(self) -> None: ...


@dataclass
class TestPattern:
    """A moving colour pattern like ROS's cam2image burger: cheap, deterministic, visibly alive."""
    width: int = 320
    height: int = 240
    _frame: int = 0

    def __post_init__(self) -> None:
        y, x = np.mgrid[0:self.height, 0:self.width]
        self._x = x.astype(np.int32)
        self._y = y.astype(np.int32)
        self._base = np.stack([x * 255 // max(self.width - 1, 1), y * 255 // max(self.height - 1, 1),
                               np.full_like(x, 96)], axis=2).astype(np.uint8)

    def read(self) -> np.ndarray:
        self._frame += 1
        frame = self._base.copy()
        # A bright square bouncing across, and a frame counter bar at the top.
        size = self.height // 4
        span_x, span_y = self.width - size, self.height - size
        t = self._frame
        px = abs((t * 4) % (2 * span_x) - span_x)
        py = abs((t * 3) % (2 * span_y) - span_y)
        frame[py:py + size, px:px + size] = (255, 255, 255)
        frame[0:6, : (t % self.width)] = (255, 40, 40)
        return frame

    def close(self) -> None:
        pass


class OpenCVSource:
    """A video device (``/dev/video0`` or an index) or a file, through OpenCV if installed."""

    def __init__(self, source: str, width: int = 320, height: int = 240) -> None:
        if importlib.util.find_spec("cv2") is None:
            raise RuntimeError("camera source needs OpenCV: pip install opencv-python-headless")
        import cv2
        self._cv2 = cv2
        self._cap = cv2.VideoCapture(int(source) if source.isdigit() else source)
        if not self._cap.isOpened():
            raise RuntimeError(f"cannot open camera source {source!r}")
        self.width, self.height = width, height

    def read(self) -> np.ndarray | None:
        ok, frame = self._cap.read()
        if not ok:
            return None
        frame = self._cv2.resize(frame, (self.width, self.height))
        rgb: np.ndarray = self._cv2.cvtColor(frame, self._cv2.COLOR_BGR2RGB)   # OpenCV is untyped
        return rgb

    def close(self) -> None:
        self._cap.release()


def open_source(spec: str = "test", width: int = 320, height: int = 240) -> FrameSource:
    """``test`` for the synthetic pattern, else a device index, device path or video file."""
    if spec in ("test", "pattern", ""):
        return TestPattern(width, height)
    return OpenCVSource(spec, width, height)


class RateKeeper:
    """Sleep to hold a fixed rate without drifting (next tick from the schedule, not from now)."""

    def __init__(self, hz: float) -> None:
        self.period = 1.0 / hz
        self._next = time.monotonic()

    def wait(self) -> None:
        self._next += self.period
        delay = self._next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        elif delay < -self.period:   # fell behind by more than a tick: resynchronise
            self._next = time.monotonic()
