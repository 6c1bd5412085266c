"""The raw and jpeg modes: one ``Image`` message a frame (rgb8/mono8 rows, or one JPEG).

The simplest wire, the thesis's: a frame is one sample, lost whole with any of its packets.
Frames are numbered by the message's sequence number and stamped with its publication stamp,
since the publisher numbers nothing itself.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..jpeg import encode_jpeg
from ..msgs import Header, Image
from ..qos import IMAGE, QoSProfile
from .base import (
    IMAGE_TYPE,
    FrameInfo,
    FrameRecords,
    ImageReceiver,
    ImageSender,
    SentFrame,
    check_quality,
    frame_array,
    sample_stamps,
    stamp_age_ms,
)


class RawImagePublisher(ImageSender):
    """One rgb8 (or mono8) ``Image`` a frame (``quality`` is taken, as every mode's, and unused)."""

    def __init__(self, node: Any, topic: str, qos: QoSProfile = IMAGE, *, quality: int = 70) -> None:
        self.publisher = node.create_publisher(Image, topic, qos)
        self.frames = 0

    def send(self, frame: Image | np.ndarray, header: Header | None = None) -> SentFrame:
        arr, header = frame_array(frame, header, type(self).__name__)
        head = header if header is not None else Header(time.time_ns(), "", self.frames)
        sent = self.publisher.publish(self._message(arr, head))
        self.frames += 1
        return SentFrame(sent.seq, sent.stamp_ns)

    def _message(self, arr: np.ndarray, head: Header) -> Image:
        return Image.from_array(arr, header=head)


class JpegImagePublisher(RawImagePublisher):
    """One JPEG ``Image`` a frame."""

    def __init__(self, node: Any, topic: str, qos: QoSProfile = IMAGE, *, quality: int = 70) -> None:
        super().__init__(node, topic, qos)
        self.quality = check_quality(quality)

    def _message(self, arr: np.ndarray, head: Header) -> Image:
        h, w = arr.shape[:2]
        return Image(head, h, w, "jpeg", 0, 0, encode_jpeg(arr, self.quality))


class WholeImageReceiver(ImageReceiver):
    """``Image`` messages in (raw or JPEG: the message says which); kept as they came, converted to
    an array when looked at."""

    message_type = Image

    def __init__(self, node: Any = None, topic: str = "", qos: QoSProfile = IMAGE, *,
                 records: FrameRecords | None = None,
                 callback: Callable[[Image, FrameInfo], None] | None = None,
                 topic_statistics: Any = None) -> None:
        self.bad_images = 0
        self.stale_images = 0
        super().__init__(node, topic, qos, records=records, callback=callback, topic_statistics=topic_statistics)

    def _file(self, img: Image, info: Any) -> None:
        publisher_id, source, received = sample_stamps(info)
        frame = int(getattr(info, "seq", img.header.seq))
        if self._order.is_stale(frame):
            self.stale_images += 1
            return
        self.strips_expected += self._order.begin(frame) + 1
        self.strips_fresh += 1
        self.complete += 1
        self._begin(frame, source, received, stamp_age_ms(source, received))
        self._show(img, FrameInfo(publisher_id, img.header.seq, source or img.header.stamp, received, IMAGE_TYPE,
                                  frame=frame, slices_received=1, slice_count=1), img.header)

    def _decode(self, img: Image) -> np.ndarray | None:
        try:
            return img.to_array()
        except Exception:   # a malformed image: counted, never raised into the viewer
            self.bad_images += 1
            return None
