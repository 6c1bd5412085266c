"""Hostile input over real Zenoh sessions (loopback): what an attacker with a plain zenoh-python
session did to a subscription or a service, and that it no longer works.

Each test sends the attack through the talker node's own session (``session.put`` of hand-made
bytes, exactly what a foreign zenoh-python session can do) and interleaves valid traffic, which
must still arrive.
"""
from __future__ import annotations

import logging
import math
import time

import msgpack
import numpy as np
import pytest
from conftest import linked_nodes
from wire_helpers import KEEP_ALL, ArmRequest, ArmResponse, raw_put

from zenoh_robot import Message, QoSProfile, message
from zenoh_robot.msgs import Header, Image, Setpoint
from zenoh_robot.services import ServiceError

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


@message(name="test_hardening/FloatStamp")
class FloatStamp(Message):
    stamp: float = 0.0
    frame_id: str = ""


@message(name="test_hardening/Stamped")
class Stamped(Message):
    """A type whose header stamp is a float (as .msg-loaded types may have): NaN is valid here."""
    header: FloatStamp = None  # type: ignore[assignment]
    value: float = 0.0

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = FloatStamp()


def _env(msg_type: type, body, pub_id: int = 1, seq: int = 1, stamp: int | None = None,
         extra: dict | None = None) -> bytes:
    return msgpack.packb(["zr1", msg_type._type_name, msg_type._type_hash, pub_id, seq,
                          time.time_ns() if stamp is None else stamp, body, extra or {}], use_bin_type=True)


# -- defect 1: one NaN stamp killed the subscription for good ------------------------------------

def test_nan_and_inf_stamps_do_not_stop_a_subscription(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[Setpoint] = []
        sub = b.create_subscription(Setpoint, "setpoint", got.append, QoSProfile(depth=50), topic_statistics=True)
        stamped: list[Stamped] = []
        ssub = b.create_subscription(Stamped, "stamped", stamped.append, QoSProfile(depth=50),
                                     topic_statistics=True)
        pub = a.create_publisher(Setpoint, "setpoint", QoSProfile(depth=50))
        spub = a.create_publisher(Stamped, "stamped", QoSProfile(depth=50))
        time.sleep(0.3)
        for bad in (float("nan"), float("inf"), -float("inf")):
            # The attacker's exact sample: a NaN where Setpoint's header has an int64 stamp.
            a.session.put(f"{ns}/setpoint", msgpack.packb(
                ["zr1", "zenoh_robot/Setpoint", Setpoint._type_hash, 1, 1, time.time_ns(),
                 [[bad, "", 0], 0, 0, -1.0, 0, False], {}]))
            # Where the stamp is a float, NaN is a valid value: it reaches the statistics hook.
            a.session.put(f"{ns}/stamped", _env(Stamped, [[bad, "x"], 1.0]))
        for i in range(5):
            pub.publish(Setpoint(x=float(i)))
            spub.publish(Stamped(FloatStamp(time.time_ns() / 1.0, "ok"), float(i)))
        assert b.spin_until(lambda: len(got) == 5 and len(stamped) == 8, 5.0), (sub.counters, ssub.counters)
        assert [m.x for m in got] == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert sub.counters.malformed == 3                  # NaN in an int64 field: never delivered
        assert ssub.counters.hook_errors == 0 and ssub.counters.internal_errors == 0
        assert sum(math.isnan(m.header.stamp) for m in stamped) == 1
        # The statistics saw the NaN/inf samples as unstamped: their age is finite.
        assert b.spin_until(lambda: ssub.statistics.last is not None, 3.0)
        age = ssub.statistics.last.message_age_ms
        assert age.sample_count == 5 and math.isfinite(age.average)
        assert not sub.pending and not sub._scheduled


def test_a_raising_hook_is_counted_and_the_subscription_keeps_draining(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[Setpoint] = []
        sub = b.create_subscription(Setpoint, "hook", got.append, KEEP_ALL)

        def bad_hook(msg, info):
            raise OverflowError("cannot convert float NaN to integer")
        sub.sample_hooks.append(bad_hook)
        pub = a.create_publisher(Setpoint, "hook", QoSProfile(depth=50))
        time.sleep(0.3)
        for i in range(200):
            pub.publish(Setpoint(x=float(i)))
        assert b.spin_until(lambda: len(got) == 200, 5.0), sub.counters
        assert sub.counters.hook_errors == 200 and not sub._scheduled


# -- defect 2: a forged sequence number silenced the real publisher ------------------------------

@pytest.mark.parametrize("jump", [999, 10**9])
def test_a_forged_sequence_number_does_not_silence_the_real_publisher(ns: str, jump: int) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[float] = []
        sub = b.create_subscription(Setpoint, "sp", lambda m: got.append(m.x), KEEP_ALL)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=50, redundancy=3))
        time.sleep(0.3)
        pub.publish(Setpoint(x=0.0))
        pub.publish(Setpoint(x=1.0))      # carries a history: the subscription now deduplicates this publisher
        assert b.spin_until(lambda: got == [0.0, 1.0], 3.0)
        # The publisher id is in every sample; the attacker claims a seq far ahead.
        a.session.put(f"{ns}/sp", _env(Setpoint, Setpoint._to_wire(Setpoint(x=-1.0)), pub.publisher_id,
                                       pub.sequence + jump))
        for i in range(2, 51):
            pub.publish(Setpoint(x=float(i)))
        assert b.spin_until(lambda: sub.counters.received == 52 and not sub.pending, 5.0), sub.counters
        assert b.spin_until(lambda: len(got) >= 52, 1.0), (got, sub.counters)
        real = [x for x in got if x >= 0]
        assert real == [float(i) for i in range(51)]       # not one real sample silenced
        assert sub.counters.lost == 0                      # and the forged jump is not "lost" samples


# -- defect 3: wrong-typed fields reached callbacks and service handlers -------------------------

WRONG_SETPOINTS = [
    [[1, "", 0], "yes", 0.0, 0.0, 0.0, False],           # x: str
    [[1, "", 0], 0.0, 0.0, 0.0, 0.0, 1],                 # is_velocity: int, not bool
    [[1, "", 0], True, 0.0, 0.0, 0.0, False],            # x: bool, not float
    [[1.5, "", 0], 0.0, 0.0, 0.0, 0.0, False],           # header.stamp: float in int64
    [[1, "", 2**63], 0.0, 0.0, 0.0, 0.0, False],         # header.seq: out of int64
    [[1, 7, 0], 0.0, 0.0, 0.0, 0.0, False],              # header.frame_id: int
    ["header", 0.0, 0.0, 0.0, 0.0, False],               # header: not a message
    [[1, "", 0], 0.0, 0.0, 0.0, 0.0],                    # a field short
    [[1, "", 0], [0.0], 0.0, 0.0, 0.0, False],           # x: list
    {"x": 1.0},                                          # not a list at all
]
WRONG_IMAGES = [
    [[1, "", 0], -1, 2, "rgb8", 0, 6, b"\x00" * 12],      # height: negative uint32
    [[1, "", 0], 2, 2, "rgb8", 0, 6, "not bytes"],       # data: str
    [[1, "", 0], 2, 2, "rgb8", 256, 6, b"\x00" * 12],     # is_bigendian: over uint8
    [[1, "", 0], 2, 2, 5, 0, 6, b"\x00" * 12],            # encoding: int
    [[1, "", 0], 2.0, 2, "rgb8", 0, 6, b"\x00" * 12],     # height: float
]


def test_wrong_typed_fields_never_reach_a_callback_and_logs_are_bounded(ns: str, caplog) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[Setpoint] = []
        images: list[Image] = []
        sub = b.create_subscription(Setpoint, "sp", got.append, KEEP_ALL)
        isub = b.create_subscription(Image, "img", images.append, KEEP_ALL)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=50))
        ipub = a.create_publisher(Image, "img", QoSProfile(depth=50))
        time.sleep(0.3)
        with caplog.at_level(logging.WARNING, logger="zenoh_robot"):
            for _ in range(20):
                for body in WRONG_SETPOINTS:
                    a.session.put(f"{ns}/sp", _env(Setpoint, body))
                for body in WRONG_IMAGES:
                    a.session.put(f"{ns}/img", _env(Image, body))
            pub.publish(Setpoint(x=3.0, is_velocity=True))
            ipub.publish(Image.from_array(np.zeros((2, 2, 3), np.uint8)))
            assert b.spin_until(lambda: got and images, 5.0), (sub.counters, isub.counters)
            assert b.spin_until(lambda: sub.counters.malformed == 200 and isub.counters.malformed == 100, 5.0)
        assert len(got) == 1 and got[0].x == 3.0 and got[0].is_velocity is True
        assert len(images) == 1 and images[0].height == 2
        malformed_lines = [r for r in caplog.records if "malformed" in r.getMessage()]
        assert 1 <= len(malformed_lines) <= 10, len(malformed_lines)      # 300 bad samples, a few lines
        assert not any(r.exc_info for r in malformed_lines)               # no traceback per sample
        assert "Setpoint.x" in " ".join(r.getMessage() for r in malformed_lines)


def test_a_service_refuses_wrong_typed_requests_naming_the_field(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        handled: list[ArmRequest] = []

        def handler(req: ArmRequest) -> ArmResponse:
            handled.append(req)
            return ArmResponse(ok=True)
        srv = b.create_service("arm", ArmRequest, ArmResponse, handler)
        client = a.create_client("arm", ArmRequest, ArmResponse)
        stop = False
        import threading
        spinner = threading.Thread(target=lambda: b.spin_until(lambda: stop, 30.0), daemon=True)
        spinner.start()
        try:
            assert client.wait_for_service(5.0)
            for body, field in (([True, float("nan"), ""], "value"), (["yes", 1, ""], "force"),
                                ([1, 1, ""], "force"), ([True, 2**40, ""], "value"),
                                ([True, 1, b"bytes"], "reason"), ([True, 1], "<body>")):
                with pytest.raises(ServiceError, match=rf"ArmRequest\.{field}") as info:
                    client._send(body, 3.0, dict_form=False).result(5.0)
                assert info.value.kind == "bad_request"
            for mapping, field in (({"force": "yes"}, "force"), ({"value": float("nan")}, "value")):
                with pytest.raises(ServiceError, match=rf"ArmRequest\.{field}"):
                    client._send(mapping, 3.0, dict_form=True).result(5.0)
            assert client.call(ArmRequest(force=True, value=3), 3.0).ok is True
        finally:
            stop = True
            spinner.join(5.0)
        assert [(r.force, r.value) for r in handled] == [(True, 3)]      # the handler saw only the valid one
        assert srv.bad_requests == 8


# -- defect 4: unbounded memory and logs from spoofed ids ----------------------------------------

def test_spoofed_publisher_ids_and_huge_histories_stay_bounded(ns: str, caplog) -> None:
    from zenoh_robot.subscription import MAX_TRACKED_PUBLISHERS
    with linked_nodes(ns) as (a, b):
        got: list[float] = []
        sub = b.create_subscription(Setpoint, "sp", lambda m: got.append(m.x), KEEP_ALL)
        time.sleep(0.3)
        body = Setpoint._to_wire(Setpoint(x=1.0))
        put = raw_put(a.session, f"{ns}/sp")
        n = 3000
        with caplog.at_level(logging.WARNING, logger="zenoh_robot"):
            for pid in range(n):      # another type, each from a new publisher id
                put(msgpack.packb(["zr1", "std_msgs/String", "0" * 16, 10**6 + pid, 1,
                                                         1, ["x"], {}]))
            for pid in range(n):      # valid samples, each from a new publisher id, redundancy on
                put(_env(Setpoint, body, pid, 5, extra={"r": [[4, 1, body]]}))
            history = {"r": [[s, 1, body] for s in range(1, 1001)]}     # 1,000 entries: the protocol allows 64
            put(_env(Setpoint, body, 7 * 10**6, 1001, extra=history))
            assert b.spin_until(lambda: sub.counters.received == 2 * n + 1 and not sub.pending, 30.0), sub.counters
        assert sub.counters.type_mismatch == n
        assert len(sub._mismatch_reported) <= MAX_TRACKED_PUBLISHERS
        assert len(sub.counters.per_publisher_seq) <= MAX_TRACKED_PUBLISHERS
        assert sub.dedup is not None and len(sub.dedup) <= sub.dedup.MAX_PUBLISHERS
        assert len(got) == n and sub.counters.malformed == 1              # the huge history: dropped whole
        mismatch_lines = [r for r in caplog.records if "type mismatch" in r.getMessage()]
        assert 1 <= len(mismatch_lines) <= 10, len(mismatch_lines)


def test_oversize_samples_are_dropped_before_they_are_copied(ns: str) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[Image] = []
        sub = b.create_subscription(Image, "img", got.append, KEEP_ALL)
        sub.max_sample_bytes = 1 << 20
        ipub = a.create_publisher(Image, "img", QoSProfile(depth=50))
        time.sleep(0.3)
        for i in range(12):
            a.session.put(f"{ns}/img", b"\x00" * ((i % 6 + 1) << 20) + b"x")    # 1-6 MB blobs
        ipub.publish(Image.from_array(np.zeros((4, 4, 3), np.uint8)))
        assert b.spin_until(lambda: got and sub.counters.received == 13, 10.0), sub.counters
        assert sub.counters.oversize == 12 and sub.counters.malformed == 0 and len(got) == 1
        assert sub._queued_bytes == 0


def test_validation_error_names_the_path() -> None:
    from zenoh_robot.message import ValidationError
    with pytest.raises(ValidationError, match=r"Setpoint\.header\.stamp: expected int64"):
        Setpoint._from_wire([[float("nan"), "", 0], 0.0, 0.0, 0.0, 0.0, False])
    assert Setpoint._from_wire([[1, "", 0], 1, 2, 3, 4, True]).x == 1.0 and \
        type(Setpoint._from_wire([[1, "", 0], 1, 2, 3, 4, True]).x) is float
    assert Header._from_wire([2**63 - 1, "", -(2**63)]).stamp == 2**63 - 1


def test_the_image_viewer_survives_hostile_slices_and_a_forged_frame_number(ns: str) -> None:
    from dataclasses import replace

    from zenoh_robot.image.sliced import ImagePublisher, ImageSlice, ImageSubscription
    from zenoh_robot.jpeg import encode_jpeg as encode_strip
    from zenoh_robot.qos import IMAGE
    with linked_nodes(ns) as (a, b):
        frames: list = []
        view = ImageSubscription(b, "image", lambda img, info: frames.append((img.height, img.width, info)))
        cam = ImagePublisher(a, "image", quality=70, pace_s=0.0)
        evil = a.create_publisher(ImageSlice, "image", IMAGE.replace(history="keep_all", depth=0))
        time.sleep(0.3)
        picture = np.full((32, 64, 3), 200, np.uint8)
        cam.publish(picture)
        assert b.spin_until(lambda: len(frames) == 1, 5.0)
        good = cam.encode(picture)[0]          # a valid slice of the next frame, to twist
        hostile = [replace(good, width=10**6), replace(good, height=10**6, width=10**6), replace(good, count=0),
                   replace(good, index=5000), replace(good, encoding="bgr16"), replace(good, row=10**6),
                   replace(good, data=encode_strip(np.zeros((8, 128, 3), np.uint8), 70)),   # wider than the frame
                   replace(good, data=b"\xff\xd8 not a jpeg")]
        for s in hostile:
            evil.publish(s)
        evil.publish(replace(good, frame=good.frame + 500))   # the transport's frame counter, forged ahead
        for _ in range(4):
            cam.publish(picture)
            time.sleep(0.02)
        assert b.spin_until(lambda: any(info.frame == 4 and info.complete for _, _, info in frames), 5.0), \
            ([info for _, _, info in frames], view.bad_slices, view.stale_slices)
        assert {2, 3, 4} <= {info.frame for _, _, info in frames}     # at most one real frame lost to the forgery
        assert view.bad_slices == len(hostile)
        assert all((h, w) == (32, 64) for h, w, _ in frames)            # never a frame of the claimed 10**6


# -- the hot path's tuple unpack checks exactly what the Envelope unpack checks ---------------------

_HEADER_VALUES = [True, 0, 1, -1, 2**64 - 1, -(2**63), 1.5, math.nan, "", "zr1", "x" * 257, b"b", None, [], {},
                  {"r": []}]


def _spec_accepts(fields: list) -> bool:
    """The envelope rules written out independently of envelope.py (its docstring and MAX_NAME_LEN)."""
    magic, name, hash_, pub, seq, stamp, _body, extra = fields
    return (magic == "zr1" and type(name) is str and type(hash_) is str and len(name) <= 256 and len(hash_) <= 256
            and all(type(v) is int for v in (pub, seq, stamp)) and type(extra) is dict
            and 0 <= pub < 2**64 and 0 <= seq < 2**64)


def test_the_tuple_unpack_accepts_exactly_the_envelopes_the_format_allows() -> None:
    from zenoh_robot import envelope
    rng = np.random.default_rng(7)
    for data in (b"", b"\xc1", msgpack.packb({"a": 1}), b"\x93\x01\x02", msgpack.packb(["zr1"] * 7)):
        with pytest.raises(envelope.MalformedSample):
            envelope.unpack_fields(data)
    accepted = 0
    for _ in range(3000):   # header fields drawn from valid and hostile values, one or two wrong at once
        fields = [envelope.MAGIC, "T", "h", 1, 2, 3, [0.5], {}]
        for i in rng.choice(8, size=int(rng.integers(1, 3)), replace=False):
            fields[i] = _HEADER_VALUES[int(rng.integers(len(_HEADER_VALUES)))]
        data = msgpack.packb(fields, use_bin_type=True)
        if not _spec_accepts(fields):
            with pytest.raises(envelope.MalformedSample):
                envelope.unpack_fields(data)
            continue
        t = envelope.unpack_fields(data)
        assert list(t) == fields[1:] or (fields[6] != fields[6])   # body may be NaN: not equal to itself
        env = envelope.unpack(data)
        assert (env.type_name, env.publisher_id, env.seq, env.extra) == (t[0], t[2], t[3], t[6])
        accepted += 1
    assert 100 < accepted < 3000   # both outcomes exercised
