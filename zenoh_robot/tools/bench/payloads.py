"""The benchmark's payloads, identical bytes for the framework and the raw baseline."""
from __future__ import annotations

import numpy as np

from zenoh_robot.jpeg import encode_jpeg
from zenoh_robot.message import Message
from zenoh_robot.msgs import Header, Image, SensorCombined, Setpoint

PAYLOADS = ("setpoint", "sensor", "image", "jpeg")


def make(name: str) -> Message:
    if name == "setpoint":
        return Setpoint(Header(0, "map", 0), 1.0, 2.0, -3.0, 0.5, False)
    if name == "sensor":
        return SensorCombined(Header(0, "base_link", 0), 123456, [0.01, -0.02, 0.03], 4000, 0,
                              [0.1, 0.2, -9.81], 4000, [0.21, 0.01, 0.42], 488.0, 21.5)
    y, x = np.mgrid[0:240, 0:320]
    frame = np.stack([(x * 3) % 256, (y * 5) % 256, ((x ^ y) * 7) % 256], axis=2).astype(np.uint8)
    if name == "image":
        return Image.from_array(frame)
    if name == "jpeg":
        return Image(Header(), 240, 320, "jpeg", 0, 0, encode_jpeg(frame, 80))
    raise ValueError(f"unknown payload {name!r}; payloads: {', '.join(PAYLOADS)}")
