"""The server's memory of recent requests: a duplicate gets the first copy's reply, never a second run."""
from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

Reply = tuple[bool, bytes]            # (ok, payload): a response envelope or an error payload
Responder = Callable[[bool, bytes], None]


@dataclass
class _CacheEntry:
    at: float
    reply: Reply | None = None                  # None while the first copy is still running
    waiters: list[Responder] = field(default_factory=list)


class IdempotencyCache:
    """Recent request digests -> reply: a duplicate is answered, never executed (see the package doc).

    Bounded three ways: ``max_entries`` (LRU), ``max_bytes`` of cached replies, ``ttl_s``; a running
    request holds at most ``max_waiters`` joined duplicates (more are dropped: their copies are
    retries of the same call, the earlier ones will get the answer).
    """

    def __init__(self, max_entries: int = 1024, max_bytes: int = 8 << 20, ttl_s: float = 120.0,
                 max_waiters: int = 32) -> None:
        self.max_entries, self.max_bytes, self.ttl_s, self.max_waiters = max_entries, max_bytes, ttl_s, max_waiters
        self._entries: OrderedDict[bytes, _CacheEntry] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.evictions = 0
        self.dropped_waiters = 0

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def nbytes(self) -> int:
        return self._bytes

    def begin(self, key: bytes, respond: Responder) -> tuple[str, Reply | None]:
        """("new", None): run it and call finish(); ("done", reply): answer with it; ("joined", None)."""
        now = time.monotonic()
        with self._lock:
            self._expire(now)
            entry = self._entries.get(key)
            if entry is None:
                self._entries[key] = _CacheEntry(now)
                self._trim()
                return "new", None
            self._entries.move_to_end(key)
            if entry.reply is not None:
                return "done", entry.reply
            if len(entry.waiters) < self.max_waiters:
                entry.waiters.append(respond)
            else:
                self.dropped_waiters += 1
            return "joined", None

    def finish(self, key: bytes, reply: Reply, keep: bool = True) -> list[Responder]:
        """Record the reply (or forget the request when ``keep`` is False); the joined waiters to answer."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                return []
            waiters, entry.waiters = entry.waiters, []
            if keep:
                entry.reply, entry.at = reply, time.monotonic()
                self._bytes += len(reply[1])
                self._trim()
            else:
                del self._entries[key]
            return waiters

    def _expire(self, now: float) -> None:
        while self._entries:
            key, entry = next(iter(self._entries.items()))
            if now - entry.at < self.ttl_s or entry.reply is None and now - entry.at < 2 * self.ttl_s:
                break
            self._drop(key)

    def _trim(self) -> None:
        while len(self._entries) > self.max_entries or self._bytes > self.max_bytes:
            self._drop(next(iter(self._entries)))
            self.evictions += 1

    def _drop(self, key: bytes) -> None:
        entry = self._entries.pop(key)
        if entry.reply is not None:
            self._bytes -= len(entry.reply[1])
