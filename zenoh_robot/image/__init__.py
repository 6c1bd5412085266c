"""Images over Zenoh: the modes a camera stream can travel in, each a sender and a receiver.

``ImageMode`` names them (str-valued: a CLI's or a config's string is a mode), and the registry
gives a mode's two ends, so a caller never switches on the mode itself::

    pub = image_publisher(mode, node, "image", qos, quality=70)   # pub.send(frame, header) -> SentFrame
    view = image_receiver(mode, node, "image", qos)               # view.latest() -> (ndarray, FrameInfo)

- raw: one rgb8 ``Image`` a frame; jpeg: one JPEG ``Image`` a frame (``whole.py``);
- sliced: JPEG strips of one datagram each, a lost packet costing a strip (``sliced.py``);
- fec: one JPEG in shares plus Reed-Solomon parity, whole or absent (``fec.py``).

Every receiver applies one stale-frame rule (``base.LatestFrame``: the newest frame wins), files
samples on the executor and decodes a frame only when asked for it (``base.py`` says why).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from ..msgs import Image
from ..qos import IMAGE, QoSProfile
from .base import MAX_SLICES, FrameInfo, FrameRecords, ImageReceiver, ImageSender, LatestFrame, SentFrame
from .fec import FecImagePublisher, FecReceiver
from .sliced import ImagePublisher, SliceReceiver
from .whole import JpegImagePublisher, RawImagePublisher, WholeImageReceiver

__all__ = [
    "ImageMode", "image_publisher", "image_receiver", "FrameInfo", "FrameRecords", "ImageReceiver",
    "ImageSender", "LatestFrame", "SentFrame", "MAX_SLICES",
]


class ImageMode(StrEnum):
    RAW = "raw"          # one rgb8 Image a frame
    JPEG = "jpeg"        # one JPEG Image a frame
    SLICED = "sliced"    # JPEG strips, one datagram each
    FEC = "fec"          # one JPEG in shares + parity sized from the loss

    @classmethod
    def _missing_(cls, value: object) -> ImageMode:
        # Enum's own error ("'x' is not a valid ImageMode") names no valid mode.
        raise ValueError(f"unknown image mode {value!r}; choose one of {', '.join(cls)}")


@dataclass(frozen=True)
class _Mode:
    publisher: Callable[..., ImageSender]
    receiver: Callable[..., ImageReceiver]


_MODES = {
    ImageMode.RAW: _Mode(RawImagePublisher, WholeImageReceiver),
    ImageMode.JPEG: _Mode(JpegImagePublisher, WholeImageReceiver),
    ImageMode.SLICED: _Mode(ImagePublisher, SliceReceiver),
    ImageMode.FEC: _Mode(FecImagePublisher, FecReceiver),
}


def image_publisher(mode: ImageMode | str, node: Any, topic: str, qos: QoSProfile = IMAGE, *,
                    quality: int = 70) -> ImageSender:
    """The sender of ``mode`` on ``topic`` (``quality``: JPEG quality, unused by raw); ValueError
    naming the modes for an unknown one."""
    return _MODES[ImageMode(mode)].publisher(node, topic, qos, quality=quality)


def image_receiver(mode: ImageMode | str, node: Any = None, topic: str = "", qos: QoSProfile = IMAGE, *,
                   records: FrameRecords | None = None,
                   callback: Callable[[Image, FrameInfo], None] | None = None,
                   topic_statistics: Any = None) -> ImageReceiver:
    """The receiver of ``mode`` on ``topic`` (without a node: fed by hand with ``add``).

    ``records``: where each frame, whole frame and piece is reported as it arrives (the stream's
    figures); ``callback``: every frame decoded as it closes, on the executor; ``topic_statistics``:
    as ``Node.create_subscription``'s."""
    return _MODES[ImageMode(mode)].receiver(node, topic, qos, records=records, callback=callback,
                                            topic_statistics=topic_statistics)
