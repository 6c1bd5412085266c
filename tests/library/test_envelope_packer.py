"""The publisher's kept-Packer envelope is byte for byte the envelope of ``envelope.pack``."""
from __future__ import annotations

import numpy as np
import pytest

from zenoh_robot import envelope

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

BODIES = [[], [1.0, 2.0, -3.0], [[0, "map", 0], 1.5, None, True], {"k": b"\x00\xff"}, "x" * 300,
          [np.float32(1.5), np.arange(3)], [2**63, -2**63]]
EXTRAS = [None, {}, {"r": 3}, {"h": [[1, 2, [0.5]]]}]


@pytest.mark.parametrize("extra", EXTRAS)
def test_packer_bytes_equal_pack(extra) -> None:
    p = envelope.EnvelopePacker("zenoh_robot/Setpoint", "ab" * 32, 2**63 - 1)
    for seq, body in enumerate(BODIES, start=1):
        want = envelope.pack("zenoh_robot/Setpoint", "ab" * 32, 2**63 - 1, seq, 1_700_000_000_000_000_000 + seq,
                             body, extra)
        got = p.pack(seq, 1_700_000_000_000_000_000 + seq, body, extra)
        assert got == want
        assert envelope.unpack_fields(got)[3] == seq


def test_a_failed_pack_leaves_nothing_behind_for_the_next() -> None:
    p = envelope.EnvelopePacker("T", "h", 1)
    with pytest.raises(TypeError, match="cannot serialise"):
        p.pack(1, 2, [1.0, object()])
    assert p.pack(2, 3, [1.0]) == envelope.pack("T", "h", 1, 2, 3, [1.0])


@pytest.mark.parametrize("obj, why", [
    ([1, 2], "not a zenoh-robot envelope"),
    (["zr0", "T", "h", 1, 1, 1, [], {}], "not a zenoh-robot envelope"),
    (["zr1", "T", "h", True, 1, 1, [], {}], "wrong field types"),
    (["zr1", "T", "h", 1, 1, 1.5, [], {}], "wrong field types"),
    (["zr1", "T" * 257, "h", 1, 1, 1, [], {}], "too long"),
    (["zr1", "T", "h", -1, 1, 1, [], {}], "out of range"),
    (["zr1", "T", "h", 1, -5, 1, [], {}], "out of range"),
])
def test_unpack_names_what_is_wrong(obj, why) -> None:
    import msgpack
    with pytest.raises(envelope.MalformedSample, match=why):
        envelope.unpack_fields(msgpack.packb(obj))
