"""One GCS in control of a drone.

The companion obeys setpoints and flight commands from one client (a GCS id) at a time:

- control is claimed by the first flight command (``take_control``, ``offboard_start``,
  ``arm``, ...) from a well-formed ``client_id`` while nobody holds it; setpoints never claim;
- it is released by ``release_control`` (a GCS sends it on exit), or when the holder is no
  longer alive: its liveliness token (``zr_gcs/<client_id>``, declared by every GCS
  session) is gone and nothing has come from it for ``lease_s``; a holder that never
  declared a token (a test node, a script) lives by the lease alone;
- another client takes over only with ``force`` (``take_control --force`` /
  ``gcs --take-control``); the previous holder is told (a ``control_lost`` event).

Everything else is refused with a reason the caller passes back to the sender.
Identity is a claim: without the secure profile (TLS + ACL) a peer can forge a client_id.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

from drone_contract.messages import valid_client_id

log = logging.getLogger("companion.control")

@dataclass
class ControlCounters:
    refused_commands: int = 0
    refused_setpoints: int = 0
    takeovers: int = 0
    releases: int = 0
    by_client: dict[str, int] = field(default_factory=dict)   # refusals per sender, bounded


class ControlArbiter:
    MAX_CLIENTS = 64      # refusal counts kept per sender (a forger can invent ids: bounded)
    MAX_TOKENS = 256

    def __init__(self, lease_s: float = 5.0) -> None:
        self.lease_s = lease_s
        self.holder = ""
        self._holder_seen = 0.0
        self._alive: set[str] = set()       # client ids with a liveliness token
        self._lock = threading.Lock()
        self.counters = ControlCounters()

    # -- liveliness ----------------------------------------------------------------
    def token(self, client_id: str, alive: bool) -> None:
        with self._lock:
            if alive and len(self._alive) < self.MAX_TOKENS:
                self._alive.add(client_id)
            elif not alive:
                self._alive.discard(client_id)

    def expire(self, now: float | None = None) -> str | None:
        """Release a holder that is gone; returns its id when it was released."""
        now = time.monotonic() if now is None else now
        with self._lock:
            h = self.holder
            if not h or h in self._alive or now - self._holder_seen <= self.lease_s:
                return None
            self.holder = ""
            self.counters.releases += 1
        log.warning("control released: %s gone (no liveliness token, silent %.1f s)", h, now - self._holder_seen)
        return h

    # -- decisions -----------------------------------------------------------------
    def admit(self, client_id: str, what: str, *, claim: bool = False, force: bool = False) -> tuple[bool, str, str]:
        """May ``client_id`` do ``what``? Returns (ok, why-not, previous holder if taken over)."""
        if not valid_client_id(client_id):
            return self._refuse(client_id, what, f"{what} refused: client_id {client_id!r} missing or malformed "
                                                 "(letters, digits, _.@:+-, at most 64)")
        now = time.monotonic()
        with self._lock:
            h = self.holder
            if h == client_id:
                self._holder_seen = now
                return True, "", ""
            if not h and claim:
                self.holder, self._holder_seen = client_id, now
                log.info("control: %s takes control (%s)", client_id, what)
                return True, "", ""
            if h and force and claim:
                self.holder, self._holder_seen = client_id, now
                self.counters.takeovers += 1
                log.warning("control: %s takes control from %s (forced, %s)", client_id, h, what)
                return True, "", h
        if not h:
            return self._refuse(client_id, what, f"{what} refused: no GCS in control; send take_control "
                                                 "or offboard_start first")
        return self._refuse(client_id, what, f"{what} refused: {h} is in control of this drone "
                                             "(take over with take_control --force)")

    def seen(self, client_id: str) -> None:
        """Something came from ``client_id``: when it holds control, its lease is renewed."""
        with self._lock:
            if client_id and client_id == self.holder:
                self._holder_seen = time.monotonic()

    def release(self, client_id: str) -> bool:
        with self._lock:
            if self.holder != client_id or not client_id:
                return False
            self.holder = ""
            self.counters.releases += 1
        log.info("control: %s released control", client_id)
        return True

    def _refuse(self, client_id: str, what: str, why: str) -> tuple[bool, str, str]:
        with self._lock:
            c = self.counters
            if what == "setpoint":
                c.refused_setpoints += 1
            else:
                c.refused_commands += 1
            key = client_id if valid_client_id(client_id) else "<invalid>"
            if key in c.by_client or len(c.by_client) < self.MAX_CLIENTS:
                c.by_client[key] = c.by_client.get(key, 0) + 1
        return False, why, ""
