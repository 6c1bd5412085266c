"""MAVLink 2 framing: a thread-safe encoder and a counting, never-raising parser.

We use pymavlink's generated ``common`` dialect directly instead of ``mavutil``'s global
dialect switch, so this package never depends on (or changes) process-wide pymavlink
state that other code in the same process might rely on.
"""
from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common, development

# pymavlink has no type information: its classes are Any to mypy, so annotations say Any
# where a MAVLink object or message goes.
mavlink2 = common   # the MAVLink 2 "common" dialect: message classes, enums, mavlink_map
MAVLink = mavlink2.MAVLink
MAVLinkMessage = mavlink2.MAVLink_message

# PX4 builds with MAVLink's "development" dialect, and names its modes with three of its messages
# that this pymavlink's ``common`` lacks (AVAILABLE_MODES 435, CURRENT_MODE 436, AVAILABLE_MODES_MONITOR
# 437). Switching the whole link to ``development`` would change every other message's class under the
# link's users; instead only these ids are decoded (CRC and signature checked) and encoded with the
# development dialect's classes. A frame carries its own crc_extra, so ``common``'s MAVLink object packs
# them with its sequence numbers and signing as it does its own messages.
EXTRA_MESSAGES: dict[int, Any] = {
    cls.id: cls for cls in (development.MAVLink_available_modes_message,
                            development.MAVLink_current_mode_message,
                            development.MAVLink_available_modes_monitor_message)
}
EXTRA_IDS: dict[str, int] = {cls.msgname: msg_id for msg_id, cls in EXTRA_MESSAGES.items()}


class _Sink:
    """pymavlink writes encoded frames to ``file.write``; route them to a callable."""

    def __init__(self, write: Callable[[bytes], None]) -> None:
        self.write = write


class Encoder:
    """Encodes and sends messages with our system/component id. Several threads send
    (stream thread, command callers), and pymavlink's sequence counter is not thread-safe,
    hence the lock."""

    def __init__(self, write: Callable[[bytes], None], system_id: int, component_id: int) -> None:
        self.mav = MAVLink(_Sink(write), srcSystem=system_id, srcComponent=component_id)
        self._extra = development.MAVLink(None)   # only its pure *_encode factories are used
        self._lock = threading.Lock()

    def send(self, msg: Any) -> None:
        with self._lock:
            self.mav.send(msg)

    def __getattr__(self, name: str) -> Any:
        # *_encode factories are pure; expose them directly (encoder.heartbeat_encode(...)).
        # The extra messages' factories come from the development dialect (see EXTRA_MESSAGES); what
        # they build is sent, like any message, through ``self.mav``.
        if name.endswith("_encode"):
            return getattr(self.mav, name) if hasattr(self.mav, name) else getattr(self._extra, name)
        raise AttributeError(name)


class Parser:
    """Turns received bytes into messages. Garbage and bad CRCs become counts, not errors.

    For datagram transports every datagram is parsed on its own: leftover bytes of a
    truncated frame are dropped and counted, so one bad datagram cannot swallow the
    start of the next good one.
    """

    def __init__(self) -> None:
        self._mav = MAVLink(None)
        self._mav.robust_parsing = True
        # Decodes EXTRA_MESSAGES, which ``common`` hands out as unchecked UNKNOWN_<id> frames.
        self._extra = development.MAVLink(None)
        self.bytes_received = 0
        self.messages = 0
        self.bad_bytes = 0
        self.bad_frames = 0
        self.crc_errors = 0
        self.unknown_messages = 0
        self.bad_signatures = 0

    @property
    def mav(self) -> Any:
        return self._mav

    @property
    def decoders(self) -> tuple[Any, Any]:
        """Both MAVLink objects that check frames: signing must be set up on each."""
        return self._mav, self._extra

    def feed(self, data: bytes, datagram: bool = False) -> list[Any]:
        if not data:
            return []
        self.bytes_received += len(data)
        out: list[Any] = []
        try:
            msgs = self._mav.parse_buffer(data) or []
        except Exception:  # robust parsing should not raise; never let it kill a thread
            msgs = []
            self._reset()
            self.bad_frames += 1
            self.bad_bytes += len(data)
        for m in msgs:
            mtype = m.get_type()
            if mtype == "BAD_DATA":
                self.bad_frames += 1
                self.bad_bytes += len(m.data)
                reason = str(getattr(m, "reason", "")).upper()
                if "CRC" in reason:
                    self.crc_errors += 1
                if "SIGNATURE" in reason:
                    self.bad_signatures += 1
                continue
            if mtype.startswith("UNKNOWN"):
                m = self._decode_extra(m)
                if m is None:
                    continue
            self.messages += 1
            out.append(m)
        if datagram:
            left = self._mav.buf_len()
            if left:
                self.bad_frames += 1
                self.bad_bytes += left
                self._reset()
        return out

    def _decode_extra(self, m: Any) -> Any:
        """An UNKNOWN_<id> frame (its ``data`` is the whole frame, unchecked) decoded with the development
        dialect when its id is one of EXTRA_MESSAGES; None (counted) when it is not or does not check out."""
        frame = bytearray(m.data)
        msg_id = _frame_msg_id(frame)
        if msg_id not in EXTRA_MESSAGES:
            self.unknown_messages += 1
            return None
        try:
            return self._extra.decode(frame)
        except Exception as exc:   # pymavlink's MAVError: a bad CRC or signature, a wrong length
            self.bad_frames += 1
            self.bad_bytes += len(frame)
            reason = str(exc).upper()
            if "CRC" in reason:
                self.crc_errors += 1
            if "SIGNATURE" in reason:
                self.bad_signatures += 1
            return None

    def _reset(self) -> None:
        self._mav.buf = bytearray()
        self._mav.buf_index = 0
        self._mav.expected_length = mavlink2.HEADER_LEN_V1 + 2


def _frame_msg_id(frame: bytes | bytearray) -> int | None:
    """The message id in a MAVLink 2 (24 bits at bytes 7-9) or 1 (byte 5) frame header."""
    if len(frame) >= 10 and frame[0] == 0xFD:
        return frame[7] | (frame[8] << 8) | (frame[9] << 16)
    if len(frame) >= 6 and frame[0] == 0xFE:
        return frame[5]
    return None


def message_id(name_or_id: str | int) -> int:
    """MAVLink message id from a name like "HIGHRES_IMU" (or an id, returned as is)."""
    if isinstance(name_or_id, int):
        return name_or_id
    extra = EXTRA_IDS.get(name_or_id.upper())
    if extra is not None:
        return extra
    try:
        return int(getattr(mavlink2, f"MAVLINK_MSG_ID_{name_or_id.upper()}"))
    except AttributeError:
        raise ValueError(f"unknown MAVLink message {name_or_id!r}") from None


def message_name(msg_id: int) -> str | None:
    cls = mavlink2.mavlink_map.get(msg_id) or EXTRA_MESSAGES.get(msg_id)
    return cls.msgname if cls is not None else None


def int_to_float_bits(v: int) -> float:
    """PX4 sends INT32 params bytewise in PARAM_VALUE's float (PARAM_ENCODE_BYTEWISE)."""
    f: float = struct.unpack("<f", struct.pack("<i", v))[0]
    return f


def float_bits_to_int(f: float) -> int:
    i: int = struct.unpack("<i", struct.pack("<f", f))[0]
    return i


SIGNING_EPOCH = 1420070400  # 2015-01-01, MAVLink 2 signing timestamps count from here


def load_signing_key(path: str) -> bytes:
    """A 32-byte MAVLink 2 secret from a key file: 64 hex characters, or else a passphrase
    hashed with SHA-256 (MAVProxy's ``signing setup <passphrase>`` convention)."""
    import hashlib
    from pathlib import Path

    text = Path(path).read_bytes().strip()
    try:
        key = bytes.fromhex(text.decode("ascii"))
        if len(key) == 32:
            return key
    except (UnicodeDecodeError, ValueError):
        pass
    return hashlib.sha256(text).digest()


def setup_signing(mav: Any, key: bytes, sign_outgoing: bool = True, link_id: int = 0) -> None:
    """pymavlink's MAVLink 2 signing on a bare MAVLink object: sign what we send and reject
    unsigned or wrongly signed frames (they reach the parser as BAD_DATA)."""
    import time

    if len(key) != 32:
        raise ValueError("a MAVLink 2 signing key is 32 bytes")
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = sign_outgoing
    mav.signing.link_id = link_id
    mav.signing.timestamp = int((time.time() - SIGNING_EPOCH) * 100_000)
    mav.signing.allow_unsigned_callback = lambda _mav, _msg_id: False
