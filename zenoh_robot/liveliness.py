"""Liveliness tokens and watches: a process says it is alive; others learn when it comes and goes.

A token (:meth:`Node.declare_liveliness_token`) lives until ``undeclare()``, until its handle is
garbage collected (keep it referenced), or until its session ends or loses its peers' lease, so a
crashed process disappears without saying goodbye. A watch
(:meth:`Node.watch_liveliness`) reports ``callback(key, alive)`` for every token matching a key
expression, those already alive first (``history``).
Zenoh 1.10 carries no liveliness over a UDP multicast session (``SessionConfig.resilient``): there
neither tokens nor watches reach other processes (:meth:`Node.peers` says what does).

Threads: Zenoh's callback thread only records the change in a bounded table and hands one drain
to the node's executor; the callback runs there, like every other callback of the node. Changes of
one key not yet delivered are merged into its latest state (a token that went and came back
before the drain is reported alive once). Keys are chosen by peers, so the table holds at most
``MAX_PENDING`` keys; changes of further keys are dropped and counted in ``dropped``.
"""
from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Protocol

import zenoh

log = logging.getLogger("zenoh_robot.liveliness")

LivelinessCallback = Callable[[str, bool], None]


class _Executor(Protocol):
    def submit(self, work: Callable[[], None]) -> None: ...


class LivelinessToken:
    """This process's liveliness token on ``key``; alive until :meth:`undeclare`, the handle's
    collection (Zenoh undeclares a dropped token: keep a reference) or the session's end."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self._token: Any = session.liveliness().declare_token(key)
        self._lock = threading.Lock()

    def undeclare(self) -> None:
        """Withdraw the token (watchers see it gone); idempotent, quiet on a closing session."""
        with self._lock:
            token, self._token = self._token, None
        if token is None:
            return
        try:
            token.undeclare()
        except zenoh.ZError as exc:   # the session may already be closing: the token goes with it
            log.debug("liveliness token %s: %s", self.key, exc)


class LivelinessWatch:
    """Tokens matching ``key_expr`` appearing and disappearing, reported on the node's executor."""

    MAX_PENDING = 1024

    def __init__(self, session: zenoh.Session, key_expr: str, callback: LivelinessCallback,
                 executor: _Executor, *, history: bool = True) -> None:
        self.key_expr = key_expr
        self._callback = callback
        self._executor = executor
        self._lock = threading.Lock()
        self._pending: OrderedDict[str, bool] = OrderedDict()
        self._scheduled = False
        self._closed = False
        self.dropped = 0
        self._sub: Any = session.liveliness().declare_subscriber(key_expr, self._on_sample, history=history)

    def _on_sample(self, sample: Any) -> None:   # Zenoh's thread: record and hand over, nothing else
        key, alive = str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            if self._closed:
                return
            if key not in self._pending and len(self._pending) >= self.MAX_PENDING:
                self.dropped += 1
                return
            self._pending[key] = alive
            if self._scheduled:
                return
            self._scheduled = True
        self._executor.submit(self._drain)

    def _drain(self) -> None:
        # One drain at a time (``_scheduled`` stays set until the table is empty), so even a
        # multi-threaded executor delivers one key's changes in order.
        while True:
            with self._lock:
                if self._closed or not self._pending:
                    self._pending.clear()
                    self._scheduled = False
                    return
                changes = list(self._pending.items())
                self._pending.clear()
            for key, alive in changes:
                try:
                    self._callback(key, alive)
                except Exception:
                    log.exception("liveliness callback for %s failed", key)

    def undeclare(self) -> None:
        """Stop watching; changes not yet delivered are dropped. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._pending.clear()
        try:
            self._sub.undeclare()
        except zenoh.ZError as exc:   # the session may already be closing
            log.debug("liveliness watch %s: %s", self.key_expr, exc)
