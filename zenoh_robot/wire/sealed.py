"""Sealed samples: a wire format that wraps another (``sealed(ENVELOPE, keyring)``) and puts an AEAD
tag (ChaCha20-Poly1305, from ``cryptography``) on every sample it sends, so it is authenticated over
any transport: UDP multicast, unicast, through a router (which forwards the bytes untouched and
needs no key). The inner format's bytes, redundancy history and repeat marker included, ride inside
unchanged.

Payload (41 bytes more than the inner one)::

    flags (1) | key id (4) | epoch (8) | counter (4) | boot (4) | ms (4) | inner bytes (plain) or ciphertext | tag (16)

Flags: 0x6A authenticate-only, 0x6B encrypted, either with :data:`REPEATED` (0x04) set when the
publisher re-sends the very same sealed bytes (a QoS with ``repeat``); the 0x5A/0x5B of the first
layout (no boot, no ms) are refused as ``malformed``. ``boot`` and ``ms`` say which start of the scope's
owner the sample was sealed for and when on that owner's clock (``wire/freshness.py``): what makes a
capture useless after either end restarts, or after ``fresh_s``. The nonce is epoch + counter
(12 bytes): the epoch is random per sealer (one per publisher, new on every start), the counter
counts every *sealed sample*; at 2**32 a new epoch is drawn. The Zenoh key expression is bound by
the key, not by the associated data: each (link key, key expression) pair seals under its own subkey,
HKDF-SHA256(secret, info = :data:`SUBKEY_INFO` + key expression), derived once per publisher or per
(subscription, key). A sample re-put on another key then fails its tag, and the associated data is
the payload's own contiguous prefix: authenticate-only seals ``head + inner`` as associated data of
an empty plaintext, encryption ``head``; no bytes are joined or copied to build it. Encryption is off
unless asked (it hides nothing a radio observer needs less than the timing; docs/security.md has the
cost).

Seal once, send many: a repeat (the same sample sent again by the repeater, ``zenoh_robot/repeater.py``)
carries the first copy's sealed bytes, so a sample costs one AEAD call to seal however many copies
leave. Redundancy history is not a copy: each sample carries its own history, so it is a new sample
with its own bytes, sealed once. Service calls (:class:`ServiceSeal`) still seal every retry and
reply copy on its own: a retry must reach the server's idempotency cache even when the first copy
did arrive.

Replay: the receiver keeps, per (key id, epoch), a 1024-slot ring of the counters accepted (slot
``counter % 1024`` holds the last counter accepted there and whether it came ``REPEATED``; newest 64
epochs per key, LRU, evictions counted). Before any AEAD work a counter is looked up: older than the
window is ``stale``; accepted before is ``duplicate`` if that accepted sample was flagged
``REPEATED`` (its copies are expected) and ``replayed`` otherwise; either way refused. Only a sample
whose tag verified marks its counter accepted. Why this is safe:

- Whichever copy arrives first is opened and delivered (loss may take the first one): the window
  holds only counters whose tag verified, so a copy is refused only if an authentic copy with the
  very same (key id, epoch, counter) was already delivered.
- An attacker replaying a captured copy sends bytes whose counter was accepted (or, if no copy had
  arrived yet, the legitimate sample itself: delivered once, as the publisher meant): a
  ``duplicate`` or ``replayed``, dropped and counted, never a second delivery. Flipping a copy's
  flags changes nothing: the verdict reads the flag stored with the accepted (authenticated) sample,
  and on a fresh counter the flags are associated data, so the tag fails.
- A forged packet naming a fresh counter goes to the tag check and fails it (``bad_tag``): it marks
  nothing, so it cannot poison the window against the real sample with that counter, nor move the
  window's top to make real counters ``stale``. A forged packet naming an accepted counter is refused
  as a duplicate without the tag check: the same outcome as checking it, for less work, and it can
  only raise the ``duplicate`` count (which is therefore a statistic, not an alarm).
- Reordering and loss within the window cost nothing: a counter is refused only if it was accepted.
- The inner deduplicator still delivers each sample once across redundancy histories.
- Across restarts (the windows are in memory): after the tag, the stamp is checked (``restarted``,
  ``unbound``, ``expired``: ``wire/freshness.py``) before the counter is marked, so a capture from
  before the owner's start, or older than ``fresh_s``, is refused and never enters a window.

Keys (``zenoh_robot.keyring``): chosen by the key expression's first segment (the drone's
namespace). A sample opens only under a key of that scope whose sender is not this node, and
unrevoked. A GCS's key is a claim: a sealed sample whose type has a ``client_id`` field must
name the key's sender there, or it is refused (so "the GCS in control" is a key, not a string).

Cost: one AEAD call per sample to seal, one per sample to open (not per copy): a duplicate copy costs
a slice, a lookup and a refusal (:class:`DuplicateSample`, which subscriptions drop without the
malformed count or log). Keys, subkeys and the current replay window are looked up only when the
sender or the keyring changes (a keyring is re-checked every ``refresh_s``, the revocation bound).
docs/security.md has the figures.

Threading: the format is per node; its refusal counters are locked (``opened``, ``sealed`` and
``duplicate`` are statistics, counted without the lock). A sealer is called under its publisher's
lock (the repeater re-sends sealed bytes, it does not seal) or by a service end's threads: its counter
is an ``itertools.count`` (atomic under the GIL), its key and epoch one tuple swapped whole. A
decoder (replay windows) belongs to one subscription, called one sample at a time.
"""
from __future__ import annotations

import dataclasses
import itertools
import os
import struct
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from time import monotonic
from typing import TYPE_CHECKING, Any, NamedTuple

from ..envelope import MalformedSample
from ..keyring import FLEET
from .format import Decoder, GraphFormat, Header, SampleEncoder, WireFormat
from .freshness import FRESH_S, OwnClock, ScopeClocks, own_clock

if TYPE_CHECKING:
    from ..keyring import Keyring, LinkKey
    from ..message import TypeSupport

AUTH_ONLY, ENCRYPTED = 0x6A, 0x6B
REPEATED = 0x04                     # a flag bit: this publisher re-sends these very bytes (its copies)
SEAL_FLAGS = frozenset((AUTH_ONLY, ENCRYPTED, AUTH_ONLY | REPEATED, ENCRYPTED | REPEATED))
_ENCRYPTED_BIT = AUTH_ONLY ^ ENCRYPTED
HEAD = struct.Struct(">B4s8sIII")   # flags, key id, epoch, counter, the owner's boot and ms (freshness.py)
HEAD_SIZE = HEAD.size               # 25
STAMP = struct.Struct(">II")        # boot, ms: the head's last 8 bytes
STAMP_AT = HEAD_SIZE - STAMP.size
TAG_SIZE = 16
OVERHEAD = HEAD_SIZE + TAG_SIZE     # 41 bytes a sample
WINDOW = 1024                       # a power of two: slot = counter & (WINDOW - 1)
MAX_EPOCHS_PER_KEY = 64
MAX_KEYS_CACHED = 256
CLAIM_FIELD = "client_id"
SUBKEY_INFO = b"zenoh-robot sealed sample v1\x00"     # HKDF info prefix; the key expression follows
_COUNTER_WRAP = 1 << 32
_SLOT = WINDOW - 1


@dataclass
class SealCounters:
    """Samples refused by the seal, by reason (``opened``: accepted)."""
    opened: int = 0
    sealed: int = 0
    unknown_key: int = 0       # a key id this node does not hold (an unknown node)
    wrong_key: int = 0         # a key of another scope, or this node's own key
    revoked: int = 0
    bad_tag: int = 0           # forged, altered, truncated, or moved to another key expression
    replayed: int = 0          # a counter accepted before, of a sample sent once (captured bytes re-put)
    duplicate: int = 0         # a counter accepted before, of a repeated sample: its copies (or a replay of one)
    stale: int = 0             # older than the replay window
    restarted: int = 0         # sealed for an earlier start of its scope's owner (a capture replayed after a restart)
    unbound: int = 0           # its sender had not heard this start of the owner (boot 0)
    expired: int = 0           # older than the freshness bound on the owner's clock (or ahead of it)
    forged_claim: int = 0      # client_id is not the sealing GCS's
    malformed: int = 0         # too short or not sealed at all
    epochs_forgotten: int = 0  # replay windows evicted (LRU)

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class ReplayWindow:
    """Counters accepted of one (key, epoch), the newest ``WINDOW`` below the highest: a fixed ring whose
    slot ``c % WINDOW`` holds ``c << 1 | repeated`` of the last counter accepted there. A counter inside
    the window was accepted iff its slot holds it (a newer one there would be ``WINDOW`` ahead, which
    makes this one stale), so moving forward clears nothing: O(1) per sample, no big-integer shifts.
    :meth:`verdict` only reads (it runs before the tag check); :meth:`accept` runs after it."""
    __slots__ = ("top", "slots")

    def __init__(self) -> None:
        self.top = -1
        self.slots = [-1] * WINDOW

    def verdict(self, counter: int) -> str | None:
        """None if ``counter`` is fresh, else "stale", "duplicate" (accepted, flagged repeated) or "replayed"."""
        if counter > self.top:
            return None
        if self.top - counter >= WINDOW:
            return "stale"
        held = self.slots[counter & _SLOT]
        if held >> 1 == counter:
            return "duplicate" if held & 1 else "replayed"
        return None

    def accept(self, counter: int, repeated: bool) -> None:
        """Mark ``counter`` accepted (its sample's tag verified)."""
        if counter > self.top:
            self.top = counter
        self.slots[counter & _SLOT] = counter << 1 | repeated


class DuplicateSample(MalformedSample):
    """A copy of a sealed sample already delivered (wire/sealed.py), refused before any AEAD work and
    counted as ``duplicate`` on the format: not malformed, so a subscription drops it silently."""


class StaleSample(MalformedSample):
    """An authentic sealed sample that is not fresh (``restarted``, ``unbound``, ``expired``): a service
    answers it with a sealed ``stale`` error, so a legitimate caller learns the owner's clock and retries."""

    def __init__(self, message: str, reason: str, inner: bytes) -> None:
        super().__init__(message)
        self.reason = reason
        self.inner = inner


FRESHNESS_REASONS = ("restarted", "unbound", "expired")


_DUPLICATE = "sealed sample refused (duplicate)"


def subkey_aead(secret: bytes, key_expr: bytes) -> Any:
    """The AEAD of ``secret`` on ``key_expr``: ChaCha20-Poly1305 under HKDF-SHA256(secret, info)."""
    from cryptography.hazmat.primitives import hashes  # the secure extra, loaded with the first sealed format
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
    from cryptography.hazmat.primitives.kdf.hkdf import HKDF
    subkey = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=SUBKEY_INFO + key_expr).derive(secret)
    return ChaCha20Poly1305(subkey)


def _invalid_tag() -> type[Exception]:
    from cryptography.exceptions import InvalidTag  # loaded with the first sealed format, not by `import zenoh_robot`
    return InvalidTag


def scope_of(key_expr: str) -> str:
    """The namespace whose keys seal ``key_expr``: its first chunk not verbatim (``@srv/uav1/x`` -> uav1)."""
    for chunk in key_expr.split("/"):
        if not chunk.startswith("@"):
            return chunk
    return ""


class _SealState(NamedTuple):
    """What one sealer seals with until the next epoch or key: swapped whole, never changed."""
    prefix: bytes       # flags + key id
    epoch: bytes
    aead: Any
    counter: Iterator[int]
    generation: int     # the keyring's reloads when this was made
    key: LinkKey


class _Sealer:
    """Seals payloads on one key expression with the node's current key for it (one publisher)."""

    def __init__(self, keyring: Keyring, key_expr: str, encrypt: bool, counters: SealCounters,
                 stamp: Callable[[], tuple[int, int]], repeated: bool = False) -> None:
        self._keyring = keyring
        self._stamp = stamp
        self._key_expr = key_expr.encode()
        self._scope = scope_of(key_expr)
        self._encrypt = encrypt
        self._flags = (ENCRYPTED if encrypt else AUTH_ONLY) | (REPEATED if repeated else 0)
        self._counters = counters
        self._lock = threading.Lock()
        self._due = 0.0
        self._state = self._renew(None, new_epoch=True)   # a publisher without a key fails here, not at a sample

    def _renew(self, old: _SealState | None, new_epoch: bool) -> _SealState:
        """The state after a reload (same key: unchanged), a rotation (new key, new epoch) or a wrap."""
        keyring = self._keyring
        key = keyring.sealing_key(self._scope)
        if key is None:
            raise ValueError(f"sealed: node {keyring.node!r} holds no link key to seal {self._scope!r}/...")
        if old is not None and key is old.key and not new_epoch:
            return old._replace(generation=keyring.reloads)
        # A new key or a spent counter: a fresh epoch, so no (subkey, nonce) pair is ever used twice.
        return _SealState(bytes((self._flags,)) + key.wire_id, os.urandom(8), subkey_aead(key.secret, self._key_expr),
                          itertools.count(1), keyring.reloads, key)

    def _slow(self, state: _SealState, counter: int) -> tuple[_SealState, int]:
        """A spent counter, a keyring reload, or its refresh due: under the lock, once per cause."""
        with self._lock:
            now = monotonic()
            if now >= self._due:
                self._due = now + self._keyring.refresh_s
                self._keyring.refresh()
            current = self._state
            if current is state:   # no other thread renewed it meanwhile
                spent = counter >= _COUNTER_WRAP
                if spent or state.generation != self._keyring.reloads:
                    current = self._state = self._renew(state, new_epoch=spent)
            if current is not state or counter >= _COUNTER_WRAP:
                counter = next(current.counter)
            return current, counter

    def __call__(self, inner: bytes) -> bytes:
        state = self._state
        counter = next(state.counter)
        if counter >= _COUNTER_WRAP or state.generation != self._keyring.reloads or monotonic() >= self._due:
            state, counter = self._slow(state, counter)
        nonce = state.epoch + counter.to_bytes(4, "big")
        head = state.prefix + nonce + STAMP.pack(*self._stamp())
        self._counters.sealed += 1     # a statistic: a lost increment between threads is fine
        if not self._encrypt:
            signed = head + inner
            tag: bytes = state.aead.encrypt(nonce, b"", signed)
            return signed + tag
        sealed_body: bytes = state.aead.encrypt(nonce, inner, head)
        return head + sealed_body


class SealingEncoder:
    """The inner format's encoder (``pack``: the inner bytes) and :meth:`sealer`, the function the
    publisher passes every sample through once (its repeats re-send the sealed bytes)."""

    def __init__(self, fmt: SealedWireFormat, inner: SampleEncoder) -> None:
        self._fmt = fmt
        self._inner = inner

    def pack(self, seq: int, stamp_ns: int, body: Any, extra: dict[str, Any] | None = None) -> bytes:
        return self._inner.pack(seq, stamp_ns, body, extra)

    def attachment(self, seq: int, stamp_ns: int) -> bytes | None:
        return None

    def sealer(self, key_expr: str, repeated: bool = False) -> Callable[[bytes], bytes]:
        return self._fmt.sealer(key_expr, repeated)


class _Opener:
    """A subscription's decoder: opens, checks replay and claim, then the inner decoder.

    The hot path serves the (key id, epoch) of the previous sample (one publisher's stream and its
    repeats) from one cached entry; any other sender, a keyring reload or the refresh timer takes
    :meth:`_lookup`, which also keeps the per-key epoch LRU in order (only a switch changes it)."""

    def __init__(self, fmt: SealedWireFormat, inner: Decoder, key_expr: str,
                 claim_index: tuple[int, ...] | None) -> None:
        self._fmt = fmt
        self._inner = inner
        self._key_expr = key_expr.encode()
        self._scope = scope_of(key_expr)
        self._claim_index = claim_index
        self._own = fmt.own if fmt.own is not None and self._scope == fmt.keyring.node else None
        self._clocks = fmt.clocks
        self._fresh_s = fmt.fresh_s
        self._windows: dict[bytes, OrderedDict[bytes, ReplayWindow]] = {}
        self._aeads: dict[bytes, tuple[LinkKey, Any]] = {}     # keys that passed the checks, this generation
        self._invalid_tag = _invalid_tag()
        self._generation = -1
        self._due = 0.0
        # The hot entry: key id + epoch (payload[1:13]) -> (key, aead, window).
        self._hot_ident = b""
        self._hot: tuple[LinkKey, Any, ReplayWindow] | None = None

    def _refuse(self, reason: str, detail: str) -> MalformedSample:
        self._fmt.count(reason)
        return MalformedSample(f"sealed sample refused ({reason}): {detail}")

    def __call__(self, payload: bytes, attachment: bytes | None) -> Header:
        inner, key = self.open(payload)
        header = self._inner(inner, attachment)
        if self._claim_index is not None:
            self.check_claim(header, key)
        self._fmt.counters.opened += 1     # one decoder per subscription: a statistic, no lock on the hot path
        return header

    def check_claim(self, header: Header, key: LinkKey) -> None:
        if self._claim_index is not None and key.role == "gcs":
            claimed: Any = header[5]
            for i in self._claim_index:     # the body's field lists, down to client_id (an action's goal.client_id)
                claimed = claimed[i] if isinstance(claimed, (list, tuple)) and len(claimed) > i else None
            if claimed != key.sender:
                raise self._refuse("forged_claim", f"client_id {str(claimed)[:64]!r} under {key.sender!r}'s key")

    def _lookup(self, ident: bytes) -> tuple[LinkKey, Any, ReplayWindow]:
        """The key, AEAD and window of ``ident`` (key id + epoch), checked; refreshes the keyring when due."""
        keyring = self._fmt.keyring
        now = monotonic()
        if now >= self._due:
            self._due = now + keyring.refresh_s
            keyring.refresh()
        if self._generation != keyring.reloads:     # a reload (rotation, revocation): look keys up again
            self._aeads.clear()
            self._generation = keyring.reloads
        wire_id, epoch = ident[:4], ident[4:]
        cached = self._aeads.get(wire_id)
        if cached is None:
            key, revoked = keyring.opening_key(wire_id)
            if key is None:
                raise self._refuse("unknown_key", f"key id {wire_id.hex()} is not in this node's keyring")
            if revoked:
                raise self._refuse("revoked", f"key {key.key_id} ({key.sender}) is revoked")
            if key.scope != self._scope or (key.sender == keyring.node and key.role != FLEET):
                raise self._refuse("wrong_key", f"key {key.key_id} ({key.sender}) does not seal {self._scope}/...")
            if len(self._aeads) >= MAX_KEYS_CACHED:
                self._aeads.clear()
            cached = self._aeads[wire_id] = (key, subkey_aead(key.secret, self._key_expr))
        key, aead = cached
        windows = self._windows.get(wire_id)
        if windows is None:
            windows = self._windows[wire_id] = OrderedDict()
        window = windows.get(epoch)
        if window is None:
            window = ReplayWindow()
        else:
            windows.move_to_end(epoch)
        return key, aead, window

    def _remember(self, ident: bytes, entry: tuple[LinkKey, Any, ReplayWindow]) -> None:
        """Keep ``entry``'s window (it held an authentic sample) and make it the hot one."""
        wire_id, epoch = ident[:4], ident[4:]
        windows = self._windows[wire_id]
        if epoch not in windows:
            windows[epoch] = entry[2]
            if len(windows) > MAX_EPOCHS_PER_KEY:
                windows.popitem(last=False)
                self._fmt.count("epochs_forgotten")
        self._hot_ident, self._hot = ident, entry

    def open(self, payload: bytes) -> tuple[bytes, LinkKey]:
        """(inner bytes, the key that sealed them) of an authentic fresh sample; MalformedSample otherwise
        (:class:`DuplicateSample` for a copy of one already opened)."""
        flags = payload[0] if len(payload) >= OVERHEAD else 0
        if flags not in SEAL_FLAGS:
            raise self._refuse("malformed", "not a sealed sample")
        ident = payload[1:13]
        entry = self._hot
        hot = ident == self._hot_ident and entry is not None and self._generation == self._fmt.keyring.reloads \
            and monotonic() < self._due
        if not hot:
            entry = self._lookup(ident)
        assert entry is not None
        key, aead, window = entry
        # Before any AEAD work: the window holds only counters whose tag verified (module doc: why).
        counter = int.from_bytes(payload[13:STAMP_AT], "big")
        verdict = window.verdict(counter)
        if verdict is not None:
            if verdict == "duplicate":
                self._fmt.counters.duplicate += 1    # a statistic, as opened: the hot path takes no lock
                raise DuplicateSample(_DUPLICATE)
            raise self._refuse(verdict, f"counter {counter} of epoch {ident[4:].hex()} under key {key.key_id}")
        nonce = payload[5:STAMP_AT]
        try:
            # Copies, not memoryviews: for samples of up to a few kB a slice costs less than a view.
            if flags & _ENCRYPTED_BIT:
                inner = aead.decrypt(nonce, payload[HEAD_SIZE:], payload[:HEAD_SIZE])
            else:
                aead.decrypt(nonce, payload[-TAG_SIZE:], payload[:-TAG_SIZE])
                inner = payload[HEAD_SIZE:-TAG_SIZE]
        except self._invalid_tag:
            raise self._refuse("bad_tag", f"tag does not verify under key {key.key_id} on this key") from None
        # After the tag (the stamp is authentic), before the window: a stale sample marks nothing.
        boot, stamp_ms = STAMP.unpack_from(payload, STAMP_AT)
        if self._own is not None:
            stale = self._own.check(boot, stamp_ms, self._fresh_s)
        else:
            stale = self._clocks.check(self._scope, boot, stamp_ms, self._fresh_s)
            if stale is None and key.sender == self._scope and key.role == "drone":
                self._clocks.learn(self._scope, boot, stamp_ms)
        if stale is not None:
            self._fmt.count(stale)
            raise StaleSample(f"sealed sample refused ({stale}): stamped boot {boot} at {stamp_ms} ms under key "
                              f"{key.key_id} ({key.sender})", stale, inner)
        # Only an authentic, fresh sample may move (or make) a window.
        if not hot:
            self._remember(ident, entry)
        window.accept(counter, bool(flags & REPEATED))
        return inner, key


def claim_index(type_support: TypeSupport | None) -> tuple[int, ...] | None:
    """Where a type's ``client_id`` field sits in its body, as field indexes from the top (None: no such
    field): a field of the type itself, else of a nested message field, e.g. an action's SendGoal request
    (``goal_id``, ``goal``: its ``client_id``), so a goal is checked as a command is."""
    if type_support is None or not dataclasses.is_dataclass(type_support.msg_type):
        return None
    return _claim_path(type_support.msg_type, depth=2)


def _claim_path(msg_type: type, depth: int) -> tuple[int, ...] | None:
    names = [f.name for f in dataclasses.fields(msg_type)]
    if CLAIM_FIELD in names:
        return (names.index(CLAIM_FIELD),)
    if depth <= 1:
        return None
    for i, spec in enumerate(getattr(msg_type, "_fields_spec", ())):
        if spec.array is None and isinstance(spec.base, type) and dataclasses.is_dataclass(spec.base):
            inner = _claim_path(spec.base, depth - 1)
            if inner is not None:
                return (i, *inner)
    return None


class SealedWireFormat:
    """A :class:`~zenoh_robot.wire.WireFormat` sealing another one's samples (see the module doc).
    Use :func:`sealed`. Publishers and subscriptions reach the key expression through
    :meth:`SealingEncoder.sealer` and :meth:`keyed_decoder`."""

    uses_attachment = False

    def __init__(self, inner: WireFormat, keyring: Keyring, encrypt: bool = False, owner: bool | None = None,
                 fresh_s: float = FRESH_S, boot_path: str | os.PathLike[str] | None = None) -> None:
        if inner.uses_attachment:
            raise ValueError(f"sealed: the {inner.name} wire format uses attachments, which a seal does not cover")
        subkey_aead(bytes(32), b"")    # the secure extra is there, or fail now
        self.inner = inner
        self.keyring = keyring
        self.encrypt = encrypt
        self.name = f"sealed({inner.name})"
        self.carries_extra = inner.carries_extra
        self.graph: GraphFormat = inner.graph
        self.counters = SealCounters()
        self._lock = threading.Lock()
        if not 0 < fresh_s < 3600:
            raise ValueError(f"sealed: fresh_s={fresh_s!r} must be a positive number of seconds under an hour")
        self.fresh_s = float(fresh_s)
        self.clocks = ScopeClocks()
        if owner is None:   # a drone's own node owns its namespace; a tool holding its key may say owner=False
            own_key = keyring.sealing_key(keyring.node)
            owner = own_key is not None and own_key.role == "drone" and own_key.sender == keyring.node
        path = Path(boot_path) if boot_path is not None else keyring.directory / f"{keyring.node}.boot"
        self.own: OwnClock | None = own_clock(path) if owner else None

    def stamp_of(self, scope: str) -> Callable[[], tuple[int, int]]:
        """What a sealer in ``scope`` stamps: this node's own clock in its own scope, else its estimate."""
        own = self.own
        if own is not None and scope == self.keyring.node:
            boot = own.boot
            return lambda: (boot, own.now_ms())
        clocks = self.clocks
        return lambda: clocks.estimate(scope)

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

    def sealer(self, key_expr: str, repeated: bool = False) -> Callable[[bytes], bytes]:
        """Seals each payload handed to it on ``key_expr`` (one per publisher or service end);
        ``repeated``: the caller re-sends the sealed bytes as they are (copies count as duplicates)."""
        if "*" in key_expr:
            raise ValueError(f"sealed: {key_expr!r} is not one key (a seal binds the key it travels on)")
        return _Sealer(self.keyring, key_expr, self.encrypt, self.counters, self.stamp_of(scope_of(key_expr)), repeated)

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


def sealed(inner: WireFormat, keyring: Keyring, encrypt: bool = False, owner: bool | None = None,
           fresh_s: float = FRESH_S, boot_path: str | os.PathLike[str] | None = None) -> SealedWireFormat:
    """``inner``'s samples, sealed with ``keyring``'s link keys (``Node(..., wire=sealed(ENVELOPE, kr))``).
    ``owner``: this node is its namespace's owner (wire/freshness.py; default: when it holds a drone key of
    its own name, whose start counter is ``boot_path``, default ``<keyring dir>/<node>.boot``); ``fresh_s``:
    the freshness bound."""
    return SealedWireFormat(inner, keyring, encrypt, owner, fresh_s, boot_path)


class ServiceSeal:
    """Sealing for one service or client on ``service_key`` (``services/``): requests are sealed on
    ``<key>/@rq`` by the caller's key (a GCS's claim checked against a ``client_id`` field), replies on
    ``<key>/@rp`` by the server's; every transmitted copy (retries, reply copies) sealed on its own,
    so the server's idempotency cache still sees one request. Thread safe (Zenoh's threads call it)."""

    def __init__(self, fmt: SealedWireFormat, service_key: str, request: TypeSupport | None,
                 response: TypeSupport | None) -> None:
        from ..envelope import unpack_fields
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
        """The request's inner envelope, or None (refused: counted on the format, logged rate-limited).
        Raises :class:`StaleSample` for an authentic request that is not fresh: the service answers it."""
        return self._open(self._requests, payload, claim=True)

    def open_reply(self, payload: bytes) -> bytes | None:
        try:
            return self._open(self._replies, payload, claim=False)
        except StaleSample:
            return None

    def _open(self, opener: _Opener, payload: bytes, claim: bool) -> bytes | None:
        try:
            with self._lock:
                inner, key = opener.open(payload)
                if claim:
                    opener.check_claim(opener._inner(inner, None), key)
                self._fmt.counters.opened += 1
            return inner
        except StaleSample:
            raise
        except MalformedSample:
            return None


def service_seal(wire: WireFormat, service_key: str, request: TypeSupport | None,
                 response: TypeSupport | None) -> ServiceSeal | None:
    """The seal of a service's calls on a node whose wire format seals (None: plain envelopes, as before)."""
    if not isinstance(wire, SealedWireFormat):
        return None
    return ServiceSeal(wire, service_key, request, response)

