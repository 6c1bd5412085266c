"""Sealed samples: a wire format that wraps another (``sealed(ENVELOPE, keyring)``) and puts an AEAD
tag (ChaCha20-Poly1305, from ``cryptography``) on every sample it sends, so it is authenticated over
any transport: UDP multicast, unicast, through a router (which forwards the bytes untouched and
needs no key). The inner format's bytes, redundancy history and repeat marker included, ride inside
unchanged.

Payload (33 bytes more than the inner one)::

    flags (1: 0x5A authenticate-only, 0x5B encrypted) | key id (4) | epoch (8) | counter (4)
    | inner bytes (plain) or ciphertext | tag (16)

The nonce is epoch + counter (12 bytes): the epoch is random per sealer (one per publisher, new
on every start), the counter counts every transmitted copy; at 2**32 a new epoch is drawn. The
associated data is the header and the Zenoh key expression, so a sample re-put on another key
fails; authenticate-only adds the inner bytes to it (AEAD of an empty plaintext). Encryption costs
~0.2 us more on a setpoint and ~12 us on a 60 kB image share (docs/security.md): off unless asked.

Replay: the receiver keeps, per (key id, epoch), a 1024-wide bitmap of counters seen (newest 64
epochs per key, LRU, evictions counted); a counter seen twice or older than the window is refused
and counted. Repeats and redundancy copies are the same sample sent again, so each transmitted copy
is sealed on its own (the publisher hands every copy to :meth:`SealingEncoder.sealer`'s function):
two copies never share a counter, a repeat is never a "replay", and the inner deduplicator still
delivers the sample once. Loss and reordering within the window cost nothing.

Keys (``zenoh_robot.keyring``): chosen by the key expression's first segment (the drone's
namespace). A sample opens only under a key of that scope whose sender is not this node, and
unrevoked. A GCS's key is a claim: a sealed sample whose type has a ``client_id`` field must
name the key's sender there, or it is refused (so "the GCS in control" is a key, not a string).

Threading: the format is per node; its counters are locked. A sealer is called under its
publisher's lock and on the repeater thread: its counter is locked. A decoder (replay windows)
belongs to one subscription, called one sample at a time.
"""
from __future__ import annotations

import dataclasses
import os
import struct
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .._wire.envelope import MalformedSample
from .format import Decoder, GraphFormat, Header, SampleEncoder, WireFormat

if TYPE_CHECKING:
    from ..keyring import Keyring, LinkKey
    from ..message import TypeSupport

AUTH_ONLY, ENCRYPTED = 0x5A, 0x5B
HEAD = struct.Struct(">B4s8sI")     # flags, key id, epoch, counter
HEAD_SIZE = HEAD.size               # 17
TAG_SIZE = 16
OVERHEAD = HEAD_SIZE + TAG_SIZE     # 33 bytes a sample
WINDOW = 1024
MAX_EPOCHS_PER_KEY = 64
MAX_KEYS_CACHED = 256
CLAIM_FIELD = "client_id"
_COUNTER_WRAP = 1 << 32


@dataclass
class SealCounters:
    """Samples refused by the seal, by reason (``opened``: accepted)."""
    opened: int = 0
    sealed: int = 0
    unknown_key: int = 0       # a key id this node does not hold (an unknown node)
    wrong_key: int = 0         # a key of another scope, or this node's own key
    revoked: int = 0
    bad_tag: int = 0           # forged, altered, or moved to another key expression
    replayed: int = 0          # a counter seen before (captured bytes re-put)
    stale: int = 0             # older than the replay window
    forged_claim: int = 0      # client_id is not the sealing GCS's
    malformed: int = 0         # too short or not sealed at all
    epochs_forgotten: int = 0  # replay windows evicted (LRU)

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class ReplayWindow:
    """Counters seen of one (key, epoch): a ``width``-bit bitmap below the highest one."""
    __slots__ = ("top", "bits", "width")

    def __init__(self, width: int = WINDOW) -> None:
        self.top = -1
        self.bits = 0       # bit i: counter top - i seen
        self.width = width

    def check(self, counter: int) -> str | None:
        """None if ``counter`` is fresh (and marks it), else "replayed" or "stale"."""
        if counter > self.top:
            shift = counter - self.top
            self.bits = ((self.bits << shift) | 1) & ((1 << self.width) - 1) if shift < self.width else 1
            self.top = counter
            return None
        age = self.top - counter
        if age >= self.width:
            return "stale"
        mask = 1 << age
        if self.bits & mask:
            return "replayed"
        self.bits |= mask
        return None


def _aead(secret: bytes) -> Any:
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305  # the secure extra
    return ChaCha20Poly1305(secret)



def _invalid_tag() -> type[Exception]:
    from cryptography.exceptions import InvalidTag  # loaded with the first sealed format, not by `import zenoh_robot`
    return InvalidTag


def scope_of(key_expr: str) -> str:
    """The namespace whose keys seal ``key_expr``: its first chunk not verbatim (``@srv/uav1/x`` -> uav1)."""
    for chunk in key_expr.split("/"):
        if not chunk.startswith("@"):
            return chunk
    return ""


class _Sealer:
    """Seals payloads on one key expression with the node's current key for it (one publisher)."""

    def __init__(self, keyring: Keyring, key_expr: str, encrypt: bool, counters: SealCounters,
                 lock: threading.Lock) -> None:
        self._keyring = keyring
        self._key_expr = key_expr.encode()
        self._scope = scope_of(key_expr)
        self._flags = ENCRYPTED if encrypt else AUTH_ONLY
        self._counters = counters
        self._counters_lock = lock
        self._lock = threading.Lock()
        self._epoch = os.urandom(8)
        self._counter = 0
        self._key: LinkKey | None = None
        self._aead: Any = None
        self._wire_id = b""
        self._generation = -1
        self._current()   # a publisher without a key fails at creation, not at the first sample

    def _current(self) -> tuple[bytes, Any]:
        keyring = self._keyring
        keyring.refresh()
        if self._key is None or self._generation != keyring.reloads:    # first use, or a reload: rotated?
            key = keyring.sealing_key(self._scope)
            if key is None:
                raise ValueError(f"sealed: node {keyring.node!r} holds no link key to seal {self._scope!r}/...")
            if key is not self._key:
                self._key, self._aead, self._wire_id = key, _aead(key.secret), key.wire_id
            self._generation = keyring.reloads
        return self._wire_id, self._aead

    def __call__(self, inner: bytes) -> bytes:
        with self._lock:
            wire_id, aead = self._current()
            self._counter += 1
            if self._counter >= _COUNTER_WRAP:
                self._epoch, self._counter = os.urandom(8), 1
            head = HEAD.pack(self._flags, wire_id, self._epoch, self._counter)
            self._counters.sealed += 1     # under this sealer's lock: close enough for a statistic
        nonce = head[5:]
        if self._flags == ENCRYPTED:
            sealed_body: bytes = aead.encrypt(nonce, inner, head + self._key_expr)
            return head + sealed_body
        tag: bytes = aead.encrypt(nonce, b"", head + self._key_expr + inner)
        return head + inner + tag


class SealingEncoder:
    """The inner format's encoder (``pack``: the inner bytes) and :meth:`sealer`, the function the
    publisher passes every transmitted copy through."""

    def __init__(self, fmt: SealedWireFormat, inner: SampleEncoder) -> None:
        self._fmt = fmt
        self._inner = inner

    def pack(self, seq: int, stamp_ns: int, body: Any, extra: dict[str, Any] | None = None) -> bytes:
        return self._inner.pack(seq, stamp_ns, body, extra)

    def attachment(self, seq: int, stamp_ns: int) -> bytes | None:
        return None

    def sealer(self, key_expr: str) -> Callable[[bytes], bytes]:
        return self._fmt.sealer(key_expr)


class _Opener:
    """A subscription's decoder: opens, checks replay and claim, then the inner decoder."""

    def __init__(self, fmt: SealedWireFormat, inner: Decoder, key_expr: str, claim_index: int | None) -> None:
        self._fmt = fmt
        self._inner = inner
        self._key_expr = key_expr.encode()
        self._scope = scope_of(key_expr)
        self._claim_index = claim_index
        self._windows: dict[bytes, OrderedDict[bytes, ReplayWindow]] = {}
        self._aeads: dict[bytes, tuple[LinkKey, Any]] = {}     # keys that passed the checks, this generation
        self._invalid_tag = _invalid_tag()
        self._generation = -1

    def _refuse(self, reason: str, detail: str) -> MalformedSample:
        self._fmt.count(reason)
        return MalformedSample(f"sealed sample refused ({reason}): {detail}")

    def __call__(self, payload: bytes, attachment: bytes | None) -> Header:
        inner, key = self.open(payload)
        header = self._inner(inner, attachment)
        self.check_claim(header, key)
        self._fmt.counters.opened += 1     # one decoder per subscription: a statistic, no lock on the hot path
        return header

    def check_claim(self, header: Header, key: LinkKey) -> None:
        if self._claim_index is not None and key.role == "gcs":
            body = header[5]
            claimed = body[self._claim_index] if isinstance(body, (list, tuple)) and len(body) > self._claim_index \
                else None
            if claimed != key.sender:
                raise self._refuse("forged_claim", f"client_id {str(claimed)[:64]!r} under {key.sender!r}'s key")

    def open(self, payload: bytes) -> tuple[bytes, LinkKey]:
        """(inner bytes, the key that sealed them) of an authentic fresh sample; MalformedSample otherwise."""
        if len(payload) < OVERHEAD or payload[0] not in (AUTH_ONLY, ENCRYPTED):
            raise self._refuse("malformed", "not a sealed sample")
        flags, wire_id, epoch, counter = HEAD.unpack_from(payload)
        keyring = self._fmt.keyring
        keyring.refresh()
        if self._generation != keyring.reloads:     # a reload (rotation, revocation): look keys up again
            self._aeads.clear()
            self._generation = keyring.reloads
        cached = self._aeads.get(wire_id)
        if cached is None:
            key, revoked = keyring.opening_key(wire_id)
            if key is None:
                raise self._refuse("unknown_key", f"key id {wire_id.hex()} is not in this node's keyring")
            if revoked:
                raise self._refuse("revoked", f"key {key.key_id} ({key.sender}) is revoked")
            if key.scope != self._scope or key.sender == keyring.node:
                raise self._refuse("wrong_key", f"key {key.key_id} ({key.sender}) does not seal {self._scope}/...")
            if len(self._aeads) >= MAX_KEYS_CACHED:
                self._aeads.clear()
            cached = self._aeads[wire_id] = (key, _aead(key.secret))
        key, aead = cached
        head, nonce = payload[:HEAD_SIZE], payload[5:HEAD_SIZE]
        try:
            if flags == ENCRYPTED:
                inner = aead.decrypt(nonce, payload[HEAD_SIZE:], head + self._key_expr)
            else:
                inner = payload[HEAD_SIZE:-TAG_SIZE]
                aead.decrypt(nonce, payload[-TAG_SIZE:], head + self._key_expr + inner)
        except self._invalid_tag:
            raise self._refuse("bad_tag", f"tag does not verify under key {key.key_id} on this key") from None
        # After the tag: only an authentic sample may move the window.
        windows = self._windows.get(wire_id)
        if windows is None:
            windows = self._windows[wire_id] = OrderedDict()
        window = windows.get(epoch)
        if window is None:
            window = windows[epoch] = ReplayWindow()
            if len(windows) > MAX_EPOCHS_PER_KEY:
                windows.popitem(last=False)
                self._fmt.count("epochs_forgotten")
        else:
            windows.move_to_end(epoch)
        verdict = window.check(counter)
        if verdict is not None:
            raise self._refuse(verdict, f"counter {counter} of epoch {epoch.hex()} under key {key.key_id}")
        return bytes(inner), key


def claim_index(type_support: TypeSupport | None) -> int | None:
    """Where a type's ``client_id`` field sits in its body (None: no such field)."""
    if type_support is None or not dataclasses.is_dataclass(type_support.msg_type):
        return None
    names = [f.name for f in dataclasses.fields(type_support.msg_type)]
    return names.index(CLAIM_FIELD) if CLAIM_FIELD in names else None


class SealedWireFormat:
    """A :class:`~zenoh_robot.wire.WireFormat` sealing another one's samples (see the module doc).
    Use :func:`sealed`. Publishers and subscriptions reach the key expression through
    :meth:`SealingEncoder.sealer` and :meth:`keyed_decoder`."""

    uses_attachment = False

    def __init__(self, inner: WireFormat, keyring: Keyring, encrypt: bool = False) -> None:
        if inner.uses_attachment:
            raise ValueError(f"sealed: the {inner.name} wire format uses attachments, which a seal does not cover")
        _aead(bytes(32))    # the secure extra is there, or fail now
        self.inner = inner
        self.keyring = keyring
        self.encrypt = encrypt
        self.name = f"sealed({inner.name})"
        self.carries_extra = inner.carries_extra
        self.graph: GraphFormat = inner.graph
        self.counters = SealCounters()
        self._lock = threading.Lock()

    def count(self, reason: str) -> None:
        """One more refusal for ``reason`` (a :class:`SealCounters` field)."""
        with self._lock:
            setattr(self.counters, reason, getattr(self.counters, reason) + 1)

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return self.counters.as_dict()

    def data_key(self, topic_key: str, type_support: TypeSupport | None) -> str:
        return self.inner.data_key(topic_key, type_support)

    def encoder(self, type_support: TypeSupport, publisher_id: int) -> SealingEncoder:
        return SealingEncoder(self, self.inner.encoder(type_support, publisher_id))

    def sealer(self, key_expr: str) -> Callable[[bytes], bytes]:
        """Seals each payload handed to it on ``key_expr`` (one per publisher or service end)."""
        if "*" in key_expr:
            raise ValueError(f"sealed: {key_expr!r} is not one key (a seal binds the key it travels on)")
        return _Sealer(self.keyring, key_expr, self.encrypt, self.counters, self._lock)

    def decoder(self, type_support: TypeSupport | None) -> Decoder:
        """A decoder that knows no key expression: it refuses every sample (the seal binds the key;
        subscriptions use :meth:`keyed_decoder`)."""
        self.inner.decoder(type_support)    # the inner format's own refusals (ValueError) still apply

        def refuse(payload: bytes, attachment: bytes | None) -> Header:
            self.count("malformed")
            raise MalformedSample("sealed sample without its key expression (use keyed_decoder)")
        return refuse

    def keyed_decoder(self, type_support: TypeSupport | None, key_expr: str) -> Decoder:
        """The decoder of samples received on ``key_expr`` (one key: the seal binds it)."""
        if "*" in key_expr:
            raise ValueError(f"sealed: cannot subscribe to {key_expr!r}: sealed samples are opened per key")
        return _Opener(self, self.inner.decoder(type_support), key_expr, claim_index(type_support))

    def __repr__(self) -> str:
        return f"sealed({self.inner!r}, {self.keyring!r}{', encrypt=True' if self.encrypt else ''})"


def sealed(inner: WireFormat, keyring: Keyring, encrypt: bool = False) -> SealedWireFormat:
    """``inner``'s samples, sealed with ``keyring``'s link keys (``Node(..., wire=sealed(ENVELOPE, kr))``)."""
    return SealedWireFormat(inner, keyring, encrypt)


class ServiceSeal:
    """Sealing for one service or client on ``service_key`` (``services/``): requests are sealed on
    ``<key>/@rq`` by the caller's key (a GCS's claim checked against a ``client_id`` field), replies on
    ``<key>/@rp`` by the server's; every transmitted copy (retries, reply copies) sealed on its own,
    so the server's idempotency cache still sees one request. Thread safe (Zenoh's threads call it)."""

    def __init__(self, fmt: SealedWireFormat, service_key: str, request: TypeSupport | None,
                 response: TypeSupport | None) -> None:
        from .._wire.envelope import unpack_fields
        self._fmt = fmt
        self._request_key = f"{service_key}/@rq"
        self._reply_key = f"{service_key}/@rp"
        self._lock = threading.Lock()
        self._requests = _Opener(fmt, unpack_fields, self._request_key, claim_index(request))
        self._replies = _Opener(fmt, unpack_fields, self._reply_key, claim_index(response))
        self._seal_request: Callable[[bytes], bytes] | None = None
        self._seal_reply: Callable[[bytes], bytes] | None = None

    def seal_request(self, inner: bytes) -> bytes:
        if self._seal_request is None:
            self._seal_request = self._fmt.sealer(self._request_key)
        return self._seal_request(inner)

    def seal_reply(self, inner: bytes) -> bytes:
        if self._seal_reply is None:
            self._seal_reply = self._fmt.sealer(self._reply_key)
        return self._seal_reply(inner)

    def open_request(self, payload: bytes) -> bytes | None:
        """The request's inner envelope, or None (refused: counted on the format, logged rate-limited)."""
        return self._open(self._requests, payload, claim=True)

    def open_reply(self, payload: bytes) -> bytes | None:
        return self._open(self._replies, payload, claim=False)

    def _open(self, opener: _Opener, payload: bytes, claim: bool) -> bytes | None:
        try:
            with self._lock:
                inner, key = opener.open(payload)
                if claim:
                    opener.check_claim(opener._inner(inner, None), key)
                self._fmt.counters.opened += 1
            return inner
        except MalformedSample:
            return None


def service_seal(wire: WireFormat, service_key: str, request: TypeSupport | None,
                 response: TypeSupport | None) -> ServiceSeal | None:
    """The seal of a service's calls on a node whose wire format seals (None: plain envelopes, as before)."""
    if not isinstance(wire, SealedWireFormat):
        return None
    return ServiceSeal(wire, service_key, request, response)

