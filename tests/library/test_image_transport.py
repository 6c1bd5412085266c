"""Sliced JPEG images: every slice one datagram, loss costs a strip, newest frame wins."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from conftest import linked_configs

from zenoh_robot import Node
from zenoh_robot.image import FrameInfo
from zenoh_robot.image.sliced import ImagePublisher, ImageSlice, ImageSubscription
from zenoh_robot.msgs import Header, Image
from zenoh_robot.qos import IMAGE
from zenoh_robot.subscription import MessageInfo


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
    # What the info says of the patched frame: one strip is frame 0's, as old as frame 0.
    assert i1.patched and not i0.patched and not i2.patched
    assert i1.fresh_fraction == (i1.slice_count - 1) / i1.slice_count and i2.fresh_fraction == 1.0
    assert i1.oldest_stamp_ns == i0.source_stamp_ns < i1.source_stamp_ns
    assert i1.oldest_strip_age_ms > i1.age_ms and i2.oldest_strip_age_ms == i2.age_ms
    assert i1.publisher_id == raw.gid and i2.publisher_id == pub.publisher.gid   # frame 1 came from `raw`
    assert sub.frames_patched == 1
    rows = 240 // i1.slice_count
    strip = slice(2 * rows, 3 * rows)
    # The lost strip shows the previous frame's pixels; the rest is frame 1.
    assert np.abs(partial[strip].astype(int) - _frame(0)[strip].astype(int)).mean() < 8
    assert np.abs(partial[:rows].astype(int) - _frame(1)[:rows].astype(int)).mean() < 8


def test_a_whole_frame_as_one_jpeg_image_decodes() -> None:
    from zenoh_robot.jpeg import encode_jpeg as encode_strip
    from zenoh_robot.msgs import Image
    frame = _frame(3)
    img = Image(height=240, width=320, encoding="jpeg", data=encode_strip(frame, 80))
    assert len(img.data) < frame.nbytes / 5
    back = img.to_array()
    assert back.shape == frame.shape and np.abs(back.astype(int) - frame.astype(int)).mean() < 6


def test_the_users_header_arrives_unchanged_with_message_info(ns: str) -> None:
    """header.seq/stamp/frame_id as the user set them; info shaped as MessageInfo; .publisher public."""
    frames: list[tuple[Image, FrameInfo]] = []
    listen, connect = linked_configs()
    with Node("viewer", namespace=ns, config=listen) as b, Node("cam", namespace=ns, config=connect) as a:
        ImageSubscription(b, "image", lambda img, info: frames.append((img, info)))
        pub = ImagePublisher(a, "image", quality=70)
        assert a.spin_until(lambda: pub.get_subscription_count() == 1, 5.0)
        assert pub.get_subscription_count() == pub.publisher.get_subscription_count()
        # A stamp from long ago: the age must come from the envelope (publication), not the header.
        sent = [Header(1_000 + i, "camera_optical", 900 + 3 * i) for i in range(3)]
        for i, head in enumerate(sent):
            assert pub.publish(Image.from_array(_frame(i), header=head)) == i   # the transport's frame number
            time.sleep(0.03)
        assert b.spin_until(lambda: len(frames) == 3, 5.0)
        pub.publish(_frame(3))              # a bare array: the transport stamps it, seq = frame number
        assert b.spin_until(lambda: len(frames) == 4, 5.0)
    assert [img.header for img, _ in frames[:3]] == sent
    assert frames[3][0].header.seq == 3 and frames[3][0].header.stamp > 10**18
    for i, (_, info) in enumerate(frames[:3]):
        assert isinstance(info, MessageInfo)
        assert (info.seq, info.frame, info.type_name) == (900 + 3 * i, i, "sensor_msgs/Image")
        assert info.publisher_id == pub.publisher.gid
        assert 10**18 < info.source_stamp_ns <= info.received_stamp_ns
        assert 0 <= info.age_ms < 60_000 and info.oldest_strip_age_ms == info.age_ms
        assert info.complete and not info.patched and info.fresh_fraction == 1.0
        assert info.slices_received == info.slice_count > 1


def _slices(i: int) -> list[ImageSlice]:
    class _Node:
        def create_publisher(self, *a: object, **kw: object) -> None:
            return None
    pub = ImagePublisher(_Node(), "x", quality=70)
    pub.frames = i
    return pub.encode(_frame(i), Header(7_000 + i, "cam", 50 + i))


class _Info:
    publisher_id = 42

    def __init__(self, frame: int) -> None:
        self.source_stamp_ns = 10**18 + frame * 10**8      # 100 ms per frame
        self.received_stamp_ns = self.source_stamp_ns + 5 * 10**6


def test_gcs_frame_keeper_shows_newest_strips_and_honest_figures() -> None:
    """The GCS's FrameKeeper (decode off the executor): patched strips, fresh-strip share, oldest age."""
    from zenoh_robot.image.sliced import SliceReceiver as FrameKeeper
    keeper = FrameKeeper()
    s0, s1, s3 = _slices(0), _slices(1), _slices(3)
    count = len(s0)
    for s in s0:
        keeper.add(s, _Info(0))
    assert keeper.complete == 1 and keeper.last_info is not None and keeper.last_info.complete
    for s in s1:
        if s.index != 2:                  # frame 1 loses strip 2
            keeper.add(s, _Info(1))
    got = keeper.latest()
    assert got is not None and got[1].frame == 0       # frame 1 is still open: frame 0 is what is shown
    for s in s3:                          # frame 2 never arrives at all; frame 3 closes frame 1
        keeper.add(s, _Info(3))
    assert keeper.frames == 3 and keeper.complete == 2 and keeper.patched == 1
    assert (keeper.strips_fresh, keeper.strips_expected) == (3 * count - 1, 4 * count)
    info = keeper.last_info
    assert info is not None and info.frame == 3 and info.seq == 53 and info.publisher_id == 42
    assert info.complete and not info.patched and info.oldest_strip_age_ms == 5.0
    # Frame 1, as shown when it closed: strip 2 is frame 0's, 100 ms older.
    keeper2 = FrameKeeper()
    for s in s0:
        keeper2.add(s, _Info(0))
    for s in s1:
        if s.index != 2:
            keeper2.add(s, _Info(1))
    keeper2.add(s3[0], _Info(3))
    i1 = keeper2.last_info
    assert i1 is not None and i1.frame == 1 and i1.seq == 51 and i1.patched and not i1.complete
    assert i1.fresh_fraction == (count - 1) / count and i1.oldest_strip_age_ms == 105.0 and i1.age_ms == 5.0
    arr, shown = keeper2.latest() or (None, None)
    assert arr is not None and shown is i1
    rows = 240 // count
    strip = slice(2 * rows, 3 * rows)
    assert np.abs(arr[strip].astype(int) - _frame(0)[strip].astype(int)).mean() < 8
    assert np.abs(arr[:rows].astype(int) - _frame(1)[:rows].astype(int)).mean() < 8
    # A slice of another geometry in the middle of a frame, and garbage: counted, never stored.
    keeper2.add(ImageSlice(Header(), 3, 1, count, 0, 10**6, 10**6, "rgb8", b""), _Info(3))
    assert keeper2.bad_slices == 1


def test_dashboard_shows_whole_fresh_frames_fresh_strips_and_the_oldest_strip() -> None:
    from types import SimpleNamespace

    import rich  # noqa: F401  (a dev dependency: missing is a failure)
    from rich.console import Console

    from gcs.app import ImageStats
    from gcs.dashboard import RateMeter, image_figures, stream_table
    from zenoh_robot.image.sliced import SliceReceiver as FrameKeeper
    keeper = FrameKeeper()
    drone = SimpleNamespace(id="uav1", frames=keeper, image=ImageStats(), streams={}, setpoints_sent=0)
    rates = RateMeter()
    assert all(math.isnan(v) for v in image_figures(drone, rates).values())   # nothing known: nothing said
    s0, s1, s3 = _slices(0), _slices(1), _slices(3)
    for s in s0:
        keeper.add(s, _Info(0))
    for s in s1[1:]:                       # frame 1 loses strip 0; frame 2 never comes
        keeper.add(s, _Info(1))
    for s in s3:
        keeper.add(s, _Info(3))
    time.sleep(0.55)                       # RateMeter's shortest window
    f = image_figures(drone, rates)
    count = len(s0)
    assert f["fresh_pct"] == pytest.approx(100 * (3 * count - 1) / (4 * count), rel=1e-3)
    assert f["whole_fps"] > 0 and f["oldest_ms"] == 5.0
    out = Console(width=160, record=True)
    out.print(stream_table(drone, rates))
    text = out.export_text()
    assert "whole fresh frames" in text and f"{3 * count - 1}/{4 * count}" in text and "1 patched" in text
