"""Generated decoders (``zenoh_robot/msg_validate.py`` build_decoder) behave exactly as the reference checker.

Message types of many shapes (every primitive, fixed arrays around the unroll limit, unbounded
arrays, bytes, nested messages past the inline depth, arrays of messages, an empty message);
hypothesis draws bodies of each, valid and corrupted at any leaf. Valid bodies decode equal
(same values, same Python types); invalid ones raise the same exception with the same message
and field path. The real message types must take the fast path (no fallback) on their own bodies.
"""
from __future__ import annotations

import copy
import math
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from zenoh_robot import msg_validate as validate
from zenoh_robot.message import Message, message, ros_field, type_support
from zenoh_robot.msg_validate import INT_RANGES, decoder_source
from zenoh_robot.msgs import Header, Image, JointState, SensorCombined, Setpoint

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

PRIMS = ["bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
         "float32", "float64", "string"]


def _make(name: str, fields: list[tuple[str, str]]) -> type:
    ns: dict[str, Any] = {"__annotations__": {f: Any for f, _ in fields}}
    for f, ros in fields:
        ns[f] = ros_field(ros)
    return message(type(name, (Message,), ns), name=f"zr_codegen_test/{name}")


Empty = _make("CgEmpty", [])
Leaf = _make("CgLeaf", [("a", "int8"), ("b", "float32"), ("s", "string")])
Deep = Leaf
for _level in range(6):     # deeper than the generated source inlines (_INLINE_DEPTH)
    Deep = _make(f"CgDeep{_level}", [("inner", Deep._type_name), ("n", "uint16")])
Wide = _make("CgWide", [(f"p_{p}", p) for p in PRIMS] + [
    (f"fa_{n}", f"float64[{n}]") for n in (0, 1, 3, validate._UNROLL, validate._UNROLL + 1)] + [
    (f"ua_{p}", f"{p}[]") for p in ("bool", "int16", "uint64", "float32", "string")] + [
    ("fix_i", "int32[4]"), ("bytes_u", "uint8[]"), ("bytes_f", "byte[4]"), ("chars", "char[]"),
    ("leaf", "CgLeaf"), ("leaves", "CgLeaf[]"), ("leaves2", "CgLeaf[2]"), ("empty", "CgEmpty"),
    ("deep", Deep._type_name), ("deeps", f"{Deep._type_name}[]")])
TYPES = [Empty, Leaf, Deep, Wide, Setpoint, SensorCombined, JointState, Image, Header]

# Values one step off a schema: the wrong type that is close (an int for a bool, a bool for an
# int, an int for a string), one past a range, a wrong length, an overflowing int.
NEAR_MISS = [0, 1, -1, 2, True, False, 0.0, 1.5, float("nan"), "", "x", b"", b"x", None, [], [0], [0.0], [True],
             ["x"], [1.5, 2], [0, 256], 255, 256, 65536, -129, 128, 1 << 31, 1 << 32, (1 << 63) - 1, 1 << 63,
             -(1 << 63) - 1, 1 << 64, 1 << 1100, {}, (1,), [[0, 1.0, ""]], [0, "", 0]]
JUNK = st.one_of(st.sampled_from(NEAR_MISS), st.sampled_from(NEAR_MISS), st.none(), st.booleans(),
                 st.integers(-(1 << 65), 1 << 65), st.just(1 << 1100),
                 st.floats(allow_nan=True), st.text(max_size=4), st.binary(max_size=4),
                 st.lists(st.integers(-3, 300), max_size=4), st.dictionaries(st.text(max_size=2), st.integers(),
                                                                              max_size=2),
                 st.tuples(st.integers()), st.lists(st.floats(), max_size=3))


def _scalar(base: str) -> st.SearchStrategy[Any]:
    if base == "bool":
        return st.booleans()
    if base in ("float32", "float64"):
        return st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(1 << 64), 1 << 64))
    if base in ("string", "wstring"):
        return st.text(max_size=6)
    lo, hi = INT_RANGES[base]
    return st.integers(lo, hi)


def body_of(cls: type, junk: bool) -> st.SearchStrategy[Any]:
    """Bodies of ``cls``; with ``junk``, any leaf (or sub-body, or length) may be wrong."""
    def maybe(s: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
        return st.one_of(s, s, s, JUNK) if junk else s

    parts = []
    for spec in cls._fields_spec:
        if spec.is_message:
            elem = st.deferred(lambda sub=spec.base: body_of(sub, junk))
        elif spec.is_bytes:
            n = spec.array if spec.array >= 0 else None
            size = {"min_size": n, "max_size": n} if n is not None else {"max_size": 6}
            elem = st.one_of(st.binary(**size), st.lists(st.integers(0, 255), **size))
            parts.append(maybe(elem))
            continue
        else:
            elem = _scalar(spec.base)
        if spec.array is None:
            parts.append(maybe(elem))
        else:
            n = spec.array if spec.array >= 0 else None
            size = {"min_size": n, "max_size": n} if n is not None else {"max_size": 4}
            parts.append(maybe(st.lists(maybe(elem), **size)))
    body = st.tuples(*parts).map(list) if parts else st.just([])
    if junk:
        body = st.one_of(body, body, body.map(tuple), body.map(lambda b: b + [0]), body.map(lambda b: b[:-1]), JUNK)
    return body


def canon(v: Any) -> Any:
    """Comparable form: message type and fields, exact Python types, NaN equal to NaN."""
    if isinstance(v, Message):
        return (type(v).__name__, tuple(canon(getattr(v, s.name)) for s in v._fields_spec))
    if type(v) is float:
        return ("float", "nan" if math.isnan(v) else v)
    if type(v) in (list, tuple):
        return (type(v).__name__, tuple(canon(x) for x in v))
    return (type(v).__name__, v)


def outcome(decode: Any, body: Any) -> Any:
    try:
        return ("ok", canon(decode(copy.deepcopy(body))))
    except Exception as exc:
        return ("raised", type(exc).__name__, str(exc), getattr(exc, "field", None))


def same_as_reference(cls: type, body: Any) -> Any:
    fast, ref = outcome(cls._from_wire, body), outcome(cls._zr_reference_from_wire, body)
    assert fast == ref, (cls.__name__, body)
    return fast


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_valid_bodies_decode_as_the_reference_does(cls: type, data: st.DataObject) -> None:
    body = data.draw(body_of(cls, junk=False))
    assert same_as_reference(cls, body)[0] == "ok"


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_corrupted_bodies_fail_with_the_reference_message_and_path(cls: type, data: st.DataObject) -> None:
    same_as_reference(cls, data.draw(body_of(cls, junk=True)))


def _paths(v: Any, path: tuple[int, ...] = ()) -> list[tuple[int, ...]]:
    out = [path]
    if type(v) is list:
        for i, x in enumerate(v):
            out += _paths(x, path + (i,))
    return out


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_one_wrong_value_anywhere_fails_as_the_reference_does(cls: type, data: st.DataObject) -> None:
    # One defect in an otherwise valid body: a fast path more permissive than the reference
    # anywhere (a type, a range, a length) shows here, not hidden behind another error.
    body = data.draw(body_of(cls, junk=False))
    path = data.draw(st.sampled_from(_paths(body)))
    bad = data.draw(JUNK)
    if not path:
        body = bad
    else:
        parent = body
        for i in path[:-1]:
            parent = parent[i]
        parent[path[-1]] = bad
    same_as_reference(cls, body)


def sample_body(cls: type) -> list[Any]:
    """A valid body of ``cls`` with every array non-empty (so every element position exists)."""
    out: list[Any] = []
    for spec in cls._fields_spec:
        n = 2 if spec.array is None or spec.array < 0 else spec.array
        if spec.is_message:
            one: Any = sample_body(spec.base)
            out.append(one if spec.array is None else [sample_body(spec.base) for _ in range(n)])
            continue
        if spec.is_bytes:
            out.append(bytes(range(1, n + 1)))
            continue
        base = spec.base
        one = (True if base == "bool" else 1.5 if base.startswith("float") else "s" if base == "string"
               else INT_RANGES[base][1])
        out.append(one if spec.array is None else [one] * n)
    return out


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
def test_every_near_miss_at_every_position_fails_as_the_reference_does(cls: type) -> None:
    # Exhaustive where the random tests sample: each position of a valid body, each near miss.
    good = sample_body(cls)
    assert same_as_reference(cls, good)[0] == "ok"
    raised = 0
    for path in _paths(good):
        for bad in NEAR_MISS:
            body = copy.deepcopy(good)
            if not path:
                body = bad
            else:
                parent = body
                for i in path[:-1]:
                    parent = parent[i]
                parent[path[-1]] = bad
            raised += same_as_reference(cls, body)[0] == "raised"
    assert raised > len(_paths(good))      # the near misses are mostly misses


def test_corruption_is_caught_at_every_depth_with_its_path() -> None:
    # A deterministic spot check beside the random ones: the path names the innermost field.
    body = [[[[[[[1, 2.0, "x"], 1], 1], 1], 1], 1], 1]
    assert type(Deep._from_wire(copy.deepcopy(body))) is Deep
    body[0][0][0][0][0][0][1] = "not a float"
    with pytest.raises(validate.ValidationError) as info:
        Deep._from_wire(body)
    assert info.value.field == "inner.inner.inner.inner.inner.inner.b"
    assert same_as_reference(Deep, body)[0] == "raised"


def test_runtime_limits_apply_to_the_fast_path(monkeypatch: pytest.MonkeyPatch) -> None:
    # Sequence and bytes limits are read when a body arrives (a deployment may change them).
    body = [[1.0, 2.0, 3.0]]
    F = _make("CgFloats", [("v", "float64[]")])
    B = _make("CgBytes", [("v", "uint8[]")])
    assert F._from_wire(body).v == [1.0, 2.0, 3.0]
    monkeypatch.setattr(validate, "MAX_SEQUENCE_LEN", 2)
    monkeypatch.setattr(validate, "MAX_BYTES_LEN", 2)
    with pytest.raises(validate.ValidationError, match="at most 2 elements"):
        F._from_wire(body)
    with pytest.raises(validate.ValidationError, match="at most 2 elements"):
        B._from_wire([b"abc"])
    assert same_as_reference(F, body)[0] == same_as_reference(B, [b"abc"])[0] == "raised"
    monkeypatch.setattr(validate, "MAX_STRING_LEN", 3)     # captured when a type is built (as the reference)
    S = _make("CgShortStr", [("s", "string")])
    assert S._from_wire(["abc"]).s == "abc"
    with pytest.raises(validate.ValidationError, match="at most 3 characters"):
        S._from_wire(["abcd"])
    assert same_as_reference(S, ["abcd"])[0] == "raised"


@pytest.mark.parametrize("msg", [
    Setpoint(Header(5, "map", 1), 1.0, 2.0, -3.0, 0.5, True),
    SensorCombined(Header(0, "base_link", 0), 123456, [0.01, -0.02, 0.03], 4000, 0, [0.1, 0.2, -9.81], 4000,
                   [0.21, 0.01, 0.42], 488.0, 21.5),
    JointState(Header(1, "j", 2), [f"j{i}" for i in range(50)], [0.1 * i for i in range(50)], [0.2] * 50, [0.3] * 50),
    Image(Header(), 2, 2, "mono8", 0, 2, bytes(4)),
], ids=lambda m: type(m).__name__)
def test_real_messages_take_the_generated_fast_path(msg: Message) -> None:
    # The fallback is always correct but as slow as before: the wire form of a real message
    # must never need it (otherwise the speed-up silently disappears).
    ts = type_support(type(msg))
    body = msgpack.unpackb(msgpack.packb(ts.encode(msg), use_bin_type=True))
    fast = type(msg)._zr_try_from_wire(body)
    assert fast is not None and fast == msg == ts.decode(body)
    src, _ = decoder_source(type(msg))
    assert "def from_wire" in src and "_slow(values)" in src


def test_ints_for_floats_are_converted_on_the_fast_path() -> None:
    sp = Setpoint._zr_try_from_wire([[5, "map", 2], 1, 2, 3, 4, True])
    assert sp is not None and type(sp.x) is float and sp.yaw == 4.0
    sc = SensorCombined._zr_try_from_wire([[0, "", 0], 1, [1, 2.5, 3], 0, 0, [0.0] * 3, 0, [0.0] * 3, 1, 2])
    assert sc is not None and [type(g) for g in sc.gyro_rad] == [float] * 3
