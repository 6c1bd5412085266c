"""Redundancy for lossy links: each sample also carries the last k samples of its publisher.

On a best-effort link a lost packet is gone; if the next packet carries the lost
sample too, the subscriber recovers it with no round trip and no waiting (unlike
reliable retransmission, whose queue makes everything behind a loss old). The
subscriber delivers in sequence order and drops what it has already delivered.

Deduplication that a forged sample cannot turn against the real publisher
--------------------------------------------------------------------------
Every sample shows its publisher id and sequence number, so anyone on the network can
send a sample that claims to be the real publisher's seq + 999. A deduplicator that only
remembers "the highest seq delivered" then drops the next 999 real samples as
duplicates: one forged packet silences a stream. Zenoh does not tell us who really sent
a sample (in zenoh-python 1.10 ``sample.source_info`` is None unless the *sender* sets
it, so it proves nothing; ``sample.timestamp``'s id likewise comes from the sender's
session), so the defence is in the protocol state instead:

* A sample is a duplicate only if its exact seq was delivered before. Each publisher id
  keeps *epochs*: an epoch remembers the highest seq it has seen (``top``) and, as a bit
  set, which of the :data:`WINDOW` seqs below ``top`` were delivered. A seq below ``top``
  that was never delivered is delivered late (out of order) instead of being dropped:
  dropping it is exactly what lets a forged high seq silence the stream.
* A seq more than :data:`AHEAD` above every epoch's ``top``, or below every epoch's
  window, opens a new epoch (a restart of the publisher, or a forgery); it never moves
  an existing epoch. A publisher keeps at most :data:`EPOCHS` epochs, least recently used
  forgotten first, so the real stream's epoch, used by every real sample, stays.
* So a forged sample costs the real stream at most the one sample whose seq it took, and
  a real sample is never dropped unless a sample with its exact seq came first. (Whoever
  can send every next seq before the publisher can impersonate it fully: that needs
  authentication, which is the transport's job, not the deduplicator's.) Forcing
  evictions (more than EPOCHS new epochs between two real samples) makes the next
  real sample start a new epoch, which delivers it: the worst case is a repeated copy
  delivered twice, never a silenced stream.
* Every table is bounded: :data:`MAX_PUBLISHERS` publisher ids (least recently seen
  forgotten, counted in ``forgotten``), EPOCHS epochs each, a WINDOW-bit set per epoch, and a
  carried history is used only if it holds at most :data:`MAX_HISTORY` entries (what a
  publisher can send).
* A flood of spoofed publisher ids cannot push out a publisher that is delivering. An id
  whose current epoch has delivered at least :data:`ESTABLISHED` of its last WINDOW seqs and
  was heard within :data:`ACTIVE_NS` is spared when it reaches the head of the full table: it
  goes back to the end (``spared``) and the next id is forgotten instead, at most
  :data:`MAX_SPARED` of them per new id (so spoofed ids that establish themselves cost a
  bounded amount of work, never an unbounded scan). Forgetting the real publisher was not
  harmless: its next sample opened a fresh entry, and the repeated copies and carried history
  of samples already delivered then came through again, late and out of order (a stale
  setpoint after a newer one).
"""
from __future__ import annotations

from collections import OrderedDict, deque
from typing import Any

HISTORY_KEY = "r"   # envelope.extra key: [[seq, stamp_ns, body], ...], oldest first
REPEAT_KEY = "n"    # envelope.extra key: how many delayed copies of this packet follow
MAX_HISTORY = 64    # the protocol's cap on both (QoSProfile.redundancy / repeat are 0..64)

WINDOW = 1024       # seqs below an epoch's top whose delivery is remembered
AHEAD = 1024        # a seq at most this far above an epoch's top continues that epoch
EPOCHS = 4          # epochs remembered per publisher id
ESTABLISHED = 16    # seqs delivered in an epoch's window that make its publisher worth keeping
ACTIVE_NS = 2_000_000_000   # ... while heard within this time (receive stamps, ns)
MAX_SPARED = 64     # established publishers moved back per eviction, at most
_MASK = (1 << WINDOW) - 1


class RedundantHistory:
    """Publisher side: the last ``k`` (seq, stamp, body) sent, to attach to the next sample."""

    def __init__(self, k: int) -> None:
        if not 1 <= k <= MAX_HISTORY:
            raise ValueError(f"redundancy needs 1 <= k <= {MAX_HISTORY}")
        self._past: deque[list[Any]] = deque(maxlen=k)

    def extra(self) -> dict[str, Any] | None:
        return {HISTORY_KEY: list(self._past)} if self._past else None

    def record(self, seq: int, stamp_ns: int, body: Any) -> None:
        self._past.append([seq, stamp_ns, body])


def check_extra(extra: dict[str, Any]) -> str | None:
    """Why a received envelope's redundancy fields break the protocol, or None if they do not."""
    history = extra.get(HISTORY_KEY)
    if history is not None and (type(history) is not list or len(history) > MAX_HISTORY):
        return f"redundancy history is not a list of at most {MAX_HISTORY} entries"
    repeats = extra.get(REPEAT_KEY)
    if repeats is not None and not (type(repeats) is int and 0 <= repeats <= MAX_HISTORY):
        return f"repeat count is not an integer 0..{MAX_HISTORY}"
    return None


class _Epoch:
    __slots__ = ("top", "seen", "heard_ns")

    def __init__(self, seq: int, now_ns: int) -> None:
        self.top = seq
        self.seen = 1          # bit i: seq top - i was delivered
        self.heard_ns = now_ns  # receive stamp of the last sample this epoch took

    def covers(self, seq: int) -> bool:
        return self.top - WINDOW < seq <= self.top + AHEAD


class Deduplicator:
    """Subscriber side, one per subscription: what each publisher has had delivered.

    ``fresh(pub_id, seq, stamp, body, extra, now_ns)`` returns the samples to deliver, oldest
    first: recovered ones from the carried history, then this one; duplicates (repeats
    of a packet, or history already delivered) yield nothing. ``now_ns`` is the sample's
    receive stamp (0: the caller keeps no time, and every established publisher counts as
    active). See the module doc for why a forged sequence number cannot silence the real
    publisher, and why a flood of spoofed ids cannot push it out.
    """

    MAX_PUBLISHERS = 1024   # bounded: forget the least recently seen publisher beyond this

    def __init__(self) -> None:
        self._pubs: OrderedDict[int, list[_Epoch]] = OrderedDict()
        self.duplicates = 0
        self.recovered = 0
        self.late = 0               # delivered after a higher seq of the same epoch
        self.epochs_started = 0     # a publisher id seen again with a seq no epoch covers
        self.history_rejected = 0   # carried histories over MAX_HISTORY entries, ignored
        self.forgotten = 0          # publisher ids dropped from the full table
        self.spared = 0             # established, active publishers moved back instead of forgotten

    def __len__(self) -> int:
        return len(self._pubs)

    def fresh(self, pub_id: int, seq: int, stamp_ns: int, body: Any,
              extra: dict[str, Any], now_ns: int = 0) -> list[tuple[int, int, Any]]:
        epochs = self._pubs.get(pub_id)
        if epochs is None:
            if len(self._pubs) >= self.MAX_PUBLISHERS:
                self._forget_one(now_ns)
            self._pubs[pub_id] = [_Epoch(seq, now_ns)]
            return [(seq, stamp_ns, body)]
        self._pubs.move_to_end(pub_id)
        for i, ep in enumerate(epochs):
            if ep.covers(seq):
                if i:
                    epochs.insert(0, epochs.pop(i))   # most recently used first
                break
        else:
            self.epochs_started += 1
            epochs.insert(0, _Epoch(seq, now_ns))
            del epochs[EPOCHS:]
            return [(seq, stamp_ns, body)]
        ep.heard_ns = now_ns
        if seq <= ep.top:
            bit = 1 << (ep.top - seq)
            if ep.seen & bit:
                self.duplicates += 1
                return []
            ep.seen |= bit
            self.late += 1
            return [(seq, stamp_ns, body)]
        out = self._recovered(ep.top, seq, extra)
        ep.seen = ((ep.seen << (seq - ep.top)) | 1) & _MASK
        ep.top = seq
        for s, _, _ in out:
            ep.seen |= 1 << (seq - s)
        out.append((seq, stamp_ns, body))
        return out

    def _forget_one(self, now_ns: int) -> None:
        # The table is full: forget the least recently seen id, sparing established publishers
        # that are still delivering (module doc: a flood of spoofed ids must not push them out).
        pubs = self._pubs
        for _ in range(MAX_SPARED):
            old_id, epochs = pubs.popitem(last=False)
            ep = epochs[0]
            if now_ns - ep.heard_ns > ACTIVE_NS or ep.seen.bit_count() < ESTABLISHED:
                self.forgotten += 1
                return
            pubs[old_id] = epochs       # back to the end: the next one goes instead
            self.spared += 1
        pubs.popitem(last=False)        # MAX_SPARED established ids in a row: the oldest goes
        self.forgotten += 1

    def _recovered(self, top: int, seq: int, extra: dict[str, Any]) -> list[tuple[int, int, Any]]:
        history = extra.get(HISTORY_KEY)
        if type(history) is not list or not history:
            return []
        if len(history) > MAX_HISTORY:
            self.history_rejected += 1
            return []
        found: dict[int, tuple[int, int, Any]] = {}
        for item in history:
            if (type(item) is list and len(item) == 3 and type(item[0]) is int and top < item[0] < seq
                    and type(item[1]) is int):
                found.setdefault(item[0], (item[0], item[1], item[2]))   # a seq twice counts once
        out = sorted(found.values(), key=lambda t: t[0])
        self.recovered += len(out)
        return out
