"""One simulated PX4 publisher: a uORB message -> PX4's payload and attachment on its key.

PX4's zenoh module sends its whole buffer: the CDR header and body, then leftover bytes up to
4 + sizeof(the uORB struct) + 24 (``px4_table.PAYLOAD_LEN``). The leftover here is random per
simulator start, as PX4's differs per run (it is stale memory, not padding), so a reader that
parses past the body is caught. The 33-byte attachment carries a sequence number from 1 per
publisher, the PX4 time in µs since boot (the sample's ``timestamp``) and PX4's GID for every
publisher.

Threading: used on the simulator's loop thread only.
"""
from __future__ import annotations

import os
from typing import Any

import zenoh

from px4_zenoh.uorb import UorbCodec
from zenoh_robot.wire.ros2 import pack_attachment

from .tokens import GID


class Outlet:
    def __init__(self, session: zenoh.Session, key: str, codec: UorbCodec, payload_len: int) -> None:
        self.key = key
        self.codec = codec
        self.payload_len = payload_len
        self._trailing = os.urandom(max(0, payload_len - 4 - codec.body_len))
        self._pub = session.declare_publisher(key)
        self.seq = 0

    def put(self, msg: Any, t_us: int) -> None:
        self.seq += 1
        self._pub.put(self.codec.encode(msg) + self._trailing, attachment=pack_attachment(self.seq, t_us, GID))

    def undeclare(self) -> None:
        self._pub.undeclare()
