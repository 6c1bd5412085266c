"""Fuzzing the receive path: random bytes, random msgpack structures, valid envelopes with wrong
field types, NaN/inf stamps, huge histories, forged sequence numbers and spoofed publisher ids,
in-process (hypothesis) and over real Zenoh sessions on loopback (seeded random).

Every test asserts that interleaved valid traffic still arrives, that the failures were counted,
that the subscription keeps draining and that its tables stay bounded.
"""
from __future__ import annotations

import math
import random
import threading
import time
from typing import Any

import msgpack
import pytest
from conftest import linked_nodes
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from wire_helpers import KEEP_ALL, ArmRequest, ArmResponse, raw_put

from zenoh_robot import QoSProfile, envelope
from zenoh_robot.message import Message, ValidationError
from zenoh_robot.msg_validate import INT_RANGES
from zenoh_robot.msgs import Header, Image, JointState, SensorCombined, Setpoint, Twist
from zenoh_robot.redundancy import EPOCHS, Deduplicator
from zenoh_robot.services import ServiceError
from zenoh_robot.subscription import MAX_TRACKED_PUBLISHERS

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

FAST = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
TYPES: list[type[Message]] = [Setpoint, SensorCombined, Image, JointState, Twist, Header, ArmRequest]

scalars = (st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats(allow_nan=True)
           | st.text(max_size=8) | st.binary(max_size=8))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=6)
                      | st.dictionaries(st.text(max_size=4), inner, max_size=3), max_leaves=20)


def conforms(msg: Any, cls: type[Message]) -> None:
    """An independent check that a decoded message holds only what its schema allows."""
    assert type(msg) is cls
    for spec in cls._fields_spec:
        v = getattr(msg, spec.name)
        items = [v] if spec.array is None or spec.is_bytes else v
        if spec.array is not None and not spec.is_bytes:
            assert type(v) is list and (spec.array < 0 or len(v) == spec.array)
        for x in items:
            if spec.is_message:
                conforms(x, spec.base)       # type: ignore[arg-type]
            elif spec.is_bytes:
                assert type(x) is bytes and (spec.array < 0 or len(x) == spec.array)
            elif spec.base == "bool":
                assert type(x) is bool
            elif spec.base in ("float32", "float64"):
                assert type(x) is float
            elif spec.base in ("string", "wstring"):
                assert type(x) is str
            else:
                lo, hi = INT_RANGES[spec.base]       # type: ignore[index]
                assert type(x) is int and lo <= x <= hi


@FAST
@given(st.binary(max_size=300))
def test_random_bytes_are_an_envelope_or_malformed(data: bytes) -> None:
    try:
        env = envelope.unpack(data)
    except envelope.MalformedSample:
        return
    assert type(env.seq) is int and type(env.publisher_id) is int and type(env.extra) is dict


@FAST
@given(st.sampled_from(TYPES), values)
def test_random_structures_decode_only_when_they_conform(cls: type[Message], body: Any) -> None:
    try:
        msg = cls._from_wire(body)
    except ValidationError:
        return
    conforms(msg, cls)


@FAST
@given(st.sampled_from(TYPES), st.data())
def test_a_valid_body_with_one_field_replaced_decodes_only_when_it_conforms(cls: type[Message], data) -> None:
    body = msgpack.unpackb(msgpack.packb(list(cls._to_wire(cls())), use_bin_type=True))
    i = data.draw(st.integers(0, len(body) - 1))
    body[i] = data.draw(values | st.sampled_from([float("nan"), float("inf"), True, 2**63, -1, "", b"", []]))
    try:
        msg = cls._from_wire(body)
    except ValidationError as exc:
        assert exc.field.split(".")[0].split("[")[0] == cls._fields_spec[i].name
        return
    conforms(msg, cls)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.integers(0, 400), st.booleans(), st.integers(0, 2**64 - 1)), max_size=300))
def test_forged_samples_never_silence_a_real_stream(forgeries) -> None:
    real_id = 42
    dedup = Deduplicator()
    by_turn: dict[int, list[tuple[bool, int]]] = {}
    for turn, same_id, seq in forgeries:
        by_turn.setdefault(turn, []).append((same_id, seq))
    taken: set[int] = set()
    delivered: list[int] = []
    for seq in range(1, 401):
        for same_id, fseq in by_turn.get(seq, []):
            pid = real_id if same_id else fseq % 5000
            for s, _, _ in dedup.fresh(pid, fseq, 0, "forged", {}):
                if pid == real_id:
                    taken.add(s)
        delivered += [s for s, _, body in dedup.fresh(real_id, seq, 0, "real", {}) if body == "real"]
    expected = [s for s in range(1, 401) if s not in taken]
    assert sorted(delivered) == expected and len(set(delivered)) == len(delivered)
    assert len(dedup) <= Deduplicator.MAX_PUBLISHERS and all(len(e) <= EPOCHS for e in dedup._pubs.values())


# -- real Zenoh sessions -----------------------------------------------------------------------

def _hostile(rng: random.Random, real_id: int, real_seq: int) -> bytes:
    """One hostile sample of a random kind."""
    ts = Setpoint._type_name, Setpoint._type_hash
    body = list(Setpoint._to_wire(Setpoint(x=-1.0)))
    kind = rng.randrange(9)
    if kind == 0:
        return rng.randbytes(rng.randrange(0, 200))
    if kind == 1:
        return msgpack.packb(_random_value(rng), use_bin_type=True)
    if kind == 2:        # a valid envelope, a field of the wrong type
        bad = list(body)
        bad[rng.randrange(len(bad))] = rng.choice(["yes", None, [1.0], {"a": 1}, b"x", 2**63, True])
        return envelope.pack(*ts, rng.randrange(2**63), 1, time.time_ns(), bad)
    if kind == 3:        # NaN / inf where the header stamp is
        return envelope.pack(*ts, rng.randrange(2**63), 1, time.time_ns(),
                             [[rng.choice([math.nan, math.inf, -math.inf]), "", 0], 0.0, 0.0, 0.0, 0.0, False])
    if kind == 4:        # a redundancy history far over the protocol's 64
        return envelope.pack(*ts, rng.randrange(2**63), 2000, time.time_ns(), body,
                             {"r": [[s, 0, body] for s in range(1, rng.randrange(65, 1500))]})
    if kind == 5:        # the real publisher's id, a seq far ahead (never one the real stream reaches)
        return envelope.pack(*ts, real_id, real_seq + rng.choice([200, 999, 10**6, 2**63]), time.time_ns(), body)
    if kind == 6:        # a spoofed id of another type
        return msgpack.packb(["zr1", "std_msgs/String", "f" * 16, rng.randrange(2**63), 1, 0, ["x"], {}])
    if kind == 7:        # a header of wrong types
        return msgpack.packb(["zr1", *ts, rng.choice([-1, "id", 1.5, True]), rng.choice([-5, 2.0, None]),
                              "now", body, []])
    return msgpack.packb(["zr1", *ts, 1, 1, 1, body, {"r": "not a list", "n": 10**6}])


def _random_value(rng: random.Random, depth: int = 0) -> Any:
    choice = rng.randrange(8 if depth < 3 else 5)
    if choice == 0:
        return rng.randrange(-(2**63), 2**63)
    if choice == 1:
        return rng.choice([math.nan, math.inf, rng.random()])
    if choice == 2:
        return "".join(chr(rng.randrange(32, 0x2FF)) for _ in range(rng.randrange(10)))
    if choice == 3:
        return rng.randbytes(rng.randrange(10))
    if choice == 4:
        return rng.choice([None, True, False])
    if choice in (5, 6):
        return [_random_value(rng, depth + 1) for _ in range(rng.randrange(9))]
    return {str(i): _random_value(rng, depth + 1) for i in range(rng.randrange(4))}


def test_a_hostile_flood_over_zenoh_does_not_stop_valid_traffic(ns: str) -> None:
    rng = random.Random(20261123)
    with linked_nodes(ns) as (a, b):
        got: list[Setpoint] = []
        sub = b.create_subscription(Setpoint, "sp", got.append, KEEP_ALL, topic_statistics=True)
        pub = a.create_publisher(Setpoint, "sp", QoSProfile(depth=100, redundancy=2))
        time.sleep(0.3)
        hostile = 0
        put = raw_put(a.session, f"{ns}/sp")
        for i in range(100):
            for _ in range(rng.randrange(0, 12)):
                put(_hostile(rng, pub.publisher_id, pub.sequence))
                hostile += 1
            pub.publish(Setpoint(x=float(i)))
            if i % 10 == 0:
                b.spin_once(0.0)       # the subscription drains while the flood goes on
        assert b.spin_until(lambda: sub.counters.received == hostile + 100 and not sub.pending, 10.0), sub.counters
        real = [m.x for m in got if m.x >= 0]
        assert real == [float(i) for i in range(100)]                  # every valid sample, in order
        assert all(type(m.x) is float and type(m.is_velocity) is bool for m in got)
        c = sub.counters
        assert c.malformed > 0 and c.type_mismatch > 0 and c.internal_errors == 0 and c.hook_errors == 0
        assert not sub._scheduled and sub._queued_bytes == 0
        assert len(c.per_publisher_seq) <= MAX_TRACKED_PUBLISHERS and len(sub._mismatch_reported) <= 1024


def test_random_service_requests_get_an_answer_and_never_reach_the_handler_malformed(ns: str) -> None:
    rng = random.Random(7)
    with linked_nodes(ns) as (a, b):
        seen: list[ArmRequest] = []

        def handler(req: ArmRequest) -> ArmResponse:
            conforms(req, ArmRequest)
            seen.append(req)
            return ArmResponse(ok=True)
        srv = b.create_service("arm", ArmRequest, ArmResponse, handler)
        client = a.create_client("arm", ArmRequest, ArmResponse)
        stop = threading.Event()
        spinner = threading.Thread(target=lambda: b.spin_until(stop.is_set, 60.0), daemon=True)
        spinner.start()
        try:
            assert client.wait_for_service(5.0)
            refused = answered = 0
            for _ in range(60):
                if rng.random() < 0.5:
                    body: Any = _random_value(rng)
                else:
                    body = [True, 1, "r"]
                    body[rng.randrange(3)] = _random_value(rng)
                dict_form = rng.random() < 0.2
                if dict_form:
                    body = {"force": _random_value(rng)} if rng.random() < 0.5 else body
                try:
                    client._send(body, 3.0, dict_form=dict_form).result(5.0)
                    answered += 1
                except ServiceError as exc:
                    assert exc.kind == "bad_request", exc
                    refused += 1
            assert client.call(ArmRequest(force=True, value=3, reason="ok"), 3.0).ok
        finally:
            stop.set()
            spinner.join(5.0)
        assert refused > 30 and answered == len(seen) - 1 and srv.bad_requests == refused


@pytest.mark.parametrize("blob_mb", [4])
def test_a_flood_of_big_samples_is_bounded_by_bytes(ns: str, blob_mb: int) -> None:
    with linked_nodes(ns) as (a, b):
        got: list[Image] = []
        sub = b.create_subscription(Image, "img", got.append, KEEP_ALL)
        sub.max_queued_bytes = 16 << 20
        time.sleep(0.3)
        blob = Image(height=1, width=blob_mb << 20, encoding="mono8", step=blob_mb << 20, data=bytes(blob_mb << 20))
        payload = envelope.pack(Image._type_name, Image._type_hash, 5, 1, time.time_ns(), Image._to_wire(blob))
        n = 30
        put = raw_put(a.session, f"{ns}/img")
        for _ in range(n):        # not spinning: everything waits in the queue
            put(payload)
        assert _wait(lambda: sub.counters.received == n, 20.0), sub.counters
        assert sub._queued_bytes <= 16 << 20 and sub.pending <= 4         # 120 MB sent, 16 MB held
        assert sub.counters.dropped >= n - 4
        assert b.spin_until(lambda: not sub.pending, 5.0) and sub._queued_bytes == 0 and 1 <= len(got) <= 4


def _wait(pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.02)
    return pred()
