"""The wire envelope every sample carries: type name and hash, publisher id, sequence, source stamp.

Layout (one msgpack array, so a sample is a single buffer and one unpack):
``[MAGIC, type_name, type_hash, publisher_id, seq, stamp_ns, body, extra]``.
``extra`` is a dict for optional fields (e.g. redundant past samples) so the
format can grow without breaking old readers; it is an empty map by default.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

MAGIC = "zr1"


class MalformedSample(ValueError):
    """Bytes on a topic that are not a zenoh-robot envelope."""


@dataclass(slots=True)
class Envelope:
    type_name: str
    type_hash: str
    publisher_id: int
    seq: int
    stamp_ns: int
    body: Any
    extra: dict[str, Any]


def _default(obj: Any) -> Any:
    # numpy values reach here only when a user put them in a message; lists are msgpack-native.
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (memoryview, bytearray)):
        return bytes(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__} in a message field")


_packer = msgpack.Packer(default=_default, use_bin_type=True, autoreset=True)


def pack(type_name: str, type_hash: str, publisher_id: int, seq: int, stamp_ns: int,
         body: Any, extra: dict[str, Any] | None = None) -> bytes:
    # A fresh Packer per call would cost ~1 us; Packer is not thread safe, so callers hold
    # the publisher's lock (publish is serialised per publisher anyway).
    return msgpack.packb((MAGIC, type_name, type_hash, publisher_id, seq, stamp_ns, body, extra or {}),
                         default=_default, use_bin_type=True)


def unpack(data: bytes | memoryview) -> Envelope:
    try:
        obj = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise MalformedSample(f"not msgpack: {exc}") from None
    if type(obj) is not list or len(obj) != 8 or obj[0] != MAGIC:
        raise MalformedSample("not a zenoh-robot envelope")
    _, type_name, type_hash, pub_id, seq, stamp, body, extra = obj
    if not (isinstance(type_name, str) and isinstance(type_hash, str) and isinstance(pub_id, int)
            and isinstance(seq, int) and isinstance(stamp, int) and isinstance(extra, dict)):
        raise MalformedSample("envelope header has wrong field types")
    return Envelope(type_name, type_hash, pub_id, seq, stamp, body, extra)
