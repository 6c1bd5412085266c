"""Sliced JPEG images: every slice one datagram, loss costs a strip, newest frame wins."""
from __future__ import annotations

import time

import numpy as np
from conftest import linked_configs

from zenoh_robot import Node
from zenoh_robot.image_transport import ImagePublisher, ImageSlice, ImageSubscription
from zenoh_robot.qos import IMAGE


def _frame(i: int) -> np.ndarray:
    y, x = np.mgrid[0:240, 0:320]
    return np.stack([(x + 4 * i) % 256, (y + 2 * i) % 256, ((x + y) // 2) % 256], axis=2).astype(np.uint8)


def test_frames_arrive_sliced_and_close_to_the_original(ns: str) -> None:
    frames = []
    slice_sizes = []
    listen, connect = linked_configs()
    with Node("viewer", namespace=ns, config=listen) as b, Node("cam", namespace=ns, config=connect) as a:
        b.create_subscription(ImageSlice, "image", lambda s: slice_sizes.append(len(s.data)), IMAGE.replace(depth=500))
        sub = ImageSubscription(b, "image", lambda img, info: frames.append((img, info)))
        pub = ImagePublisher(a, "image", quality=70)
        time.sleep(0.3)
        for i in range(5):
            pub.publish(_frame(i))
            time.sleep(0.03)
        assert b.spin_until(lambda: len(frames) >= 5, 5.0)
    img, info = frames[-1]
    assert info.complete and info.frame == 4 and info.slice_count > 1
    err = np.abs(img.to_array().astype(int) - _frame(4).astype(int)).mean()
    assert err < 8, f"mean abs error {err}"
    assert max(slice_sizes) <= 1400, "a slice would not fit one datagram"
    assert sub.frames_complete == 5 and pub.oversize_slices == 0


def test_a_lost_slice_costs_a_strip_and_old_frames_are_dropped(ns: str) -> None:
    frames = []
    listen, connect = linked_configs()
    with Node("viewer", namespace=ns, config=listen) as b, Node("cam", namespace=ns, config=connect) as a:
        sub = ImageSubscription(b, "image", lambda img, info: frames.append((img.to_array().copy(), info)))
        pub = ImagePublisher(a, "image", quality=70)
        raw = a.create_publisher(ImageSlice, "image", IMAGE)   # same link as pub: no reordering
        time.sleep(0.3)
        pub.publish(_frame(0))
        assert b.spin_until(lambda: len(frames) == 1, 5.0)
        # Frame 1 loses slice 2: publish its slices by hand, skipping one.
        pub.frames = 1
        sent = pub.encode(_frame(1))
        for s in sent:
            if s.index != 2:
                raw.publish(s)
        old = sent[0]
        pub.frames = 2
        pub.publish(_frame(2))         # a newer frame closes frame 1, partial
        assert b.spin_until(lambda: len(frames) == 3, 5.0)
        raw.publish(old)               # a late slice of frame 1: stale, dropped
        assert b.spin_until(lambda: sub.stale_slices == 1, 2.0)
        assert len(frames) == 3
    (_, i0), (partial, i1), (_, i2) = frames
    assert i0.complete and not i1.complete and i1.slices_received == i1.slice_count - 1 and i2.complete
    rows = 240 // i1.slice_count
    strip = slice(2 * rows, 3 * rows)
    # The lost strip shows the previous frame's pixels; the rest is frame 1.
    assert np.abs(partial[strip].astype(int) - _frame(0)[strip].astype(int)).mean() < 8
    assert np.abs(partial[:rows].astype(int) - _frame(1)[:rows].astype(int)).mean() < 8


def test_a_whole_frame_as_one_jpeg_image_decodes() -> None:
    from zenoh_robot.image_transport import encode_strip
    from zenoh_robot.msgs import Image
    frame = _frame(3)
    img = Image(height=240, width=320, encoding="jpeg", data=encode_strip(frame, 80))
    assert len(img.data) < frame.nbytes / 5
    back = img.to_array()
    assert back.shape == frame.shape and np.abs(back.astype(int) - frame.astype(int)).mean() < 6
