"""Why a service call failed: the exceptions a caller catches and the error payload servers reply with.

A failure a server reports travels as ``reply_err`` (or a put flagged as an error) carrying the
msgpack array ``["zr-err", kind, text]``, so a client tells it apart from Zenoh's own errors.
"""
from __future__ import annotations

import msgpack

_ERR_MAGIC = "zr-err"


class ServiceCallError(Exception):
    """Base of every failed service call."""


class ServiceTimeout(ServiceCallError):
    """No reply within the timeout (the server may be slow, busy or not spinning)."""


class ServiceUnavailable(ServiceCallError):
    """No server for the service."""


class ServiceError(ServiceCallError):
    """The server replied with an error; ``kind`` says which (handler, type, bad_request, busy)."""

    def __init__(self, message: str, kind: str = "handler") -> None:
        super().__init__(message)
        self.kind = kind


def _error_payload(kind: str, text: str) -> bytes:
    return msgpack.packb([_ERR_MAGIC, kind, text], use_bin_type=True)


def decode_error(payload: bytes) -> tuple[str, str] | None:
    """(kind, text) of one of our error replies, or None for another error (Zenoh's Timeout)."""
    try:
        obj = msgpack.unpackb(payload, raw=False)
    except Exception:
        return None
    if isinstance(obj, list) and len(obj) == 3 and obj[0] == _ERR_MAGIC:
        return str(obj[1]), str(obj[2])
    return None
