"""A drone's standing problems: a second companion with its id, a matched stream that sends nothing.

Each is raised once (logged as a warning, kept in ``log`` for the summary) and shown on the
dashboard and the status line while it lasts; clearing it says so at info. Raised and cleared on
the executor (events, the state callback, the claim watch), read by the dashboard's thread and the
summary: under a lock, and read as copies.
"""
from __future__ import annotations

import logging
import threading

from zenoh_robot import SubscriptionEventCallbacks
from zenoh_robot.events import SilentStreamInfo

log = logging.getLogger("gcs")
KEPT = 20      # raised alerts kept for the summary


class Alerts:
    def __init__(self, drone_id: str) -> None:
        self.drone_id = drone_id
        self._now: dict[str, str] = {}
        self._log: list[str] = []
        self._lock = threading.Lock()

    @property
    def now(self) -> dict[str, str]:
        """The problems standing now, kind -> text (a copy)."""
        with self._lock:
            return dict(self._now)

    @property
    def log(self) -> list[str]:
        """Every problem raised (the last ``KEPT``), as ``kind: text`` (a copy)."""
        with self._lock:
            return list(self._log)

    def raise_(self, kind: str, text: str) -> None:
        with self._lock:
            new = self._now.get(kind) != text
            self._now[kind] = text
            if new:
                self._log.append(f"{kind}: {text}")
                del self._log[:-KEPT]
        if new:
            log.warning("%s: %s", self.drone_id, text)

    def clear(self, kind: str, why: str) -> None:
        with self._lock:
            gone = self._now.pop(kind, None) is not None
        if gone:
            log.info("%s: %s", self.drone_id, why)

    def silence_events(self, stream: str) -> SubscriptionEventCallbacks:
        """A subscription's events that raise ``silent_<stream>`` (zenoh_robot.silence) and clear it."""
        def on_silent(s: SilentStreamInfo) -> None:
            text = s.describe(f"{self.drone_id} {stream}")
            if s.silent:
                self.raise_(f"silent_{stream}", text)
            else:
                self.clear(f"silent_{stream}", text)
        return SubscriptionEventCallbacks(silent_stream=on_silent)
