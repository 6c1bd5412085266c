"""One GCS in control of a drone.

The companion obeys setpoints and flight commands from one client (a GCS id) at a time:

- control is claimed by the first flight command (``take_control``, ``offboard_start``,
  ``arm``, ...) from a well-formed ``client_id`` while nobody holds it; setpoints never claim;
- it is given up by ``release_control`` (a GCS sends it on exit; during an offboard session
  the command desk puts the drone in HOLD first), or handed over: the holder offers control
  to a named GCS (``hand_over``), which confirms with ``take_control`` within ``HAND_OVER_S``;
  until then the holder keeps it, and an offer nobody confirms changes nothing;
- a holder that is gone (its liveliness token ``zr_gcs/<client_id>`` is gone and nothing
  has come from it for ``lease_s``) is released only when the caller says the vehicle may
  be left without a controller (landed or disarmed, no session): control never lapses in
  the air, where the setpoint deadline has already put the drone in HOLD. A holder whose
  token never arrives (a test node, a script, a GCS over Zenoh's UDP multicast transport,
  which carries no liveliness) lives by the lease alone: its setpoints, commands and the
  presence a running GCS sends twice a second (``<id>/presence``) each renew it (``seen``),
  so a GCS waiting for a landing keeps control, and one that stops sending loses it;
- another client takes over only with ``force`` (``take_control --force`` /
  ``gcs --take-control``); the previous holder is told (a ``control_lost`` event).

Everything else is refused with a reason the caller passes back to the sender.
Identity is a claim: without the secure profile (TLS + ACL) a peer can forge a client_id.
Threads: any; every decision is taken under one lock.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

from drone_contract.commands import HAND_OVER_S
from drone_contract.messages import valid_client_id

log = logging.getLogger("companion.control")


@dataclass
class ControlCounters:
    refused_commands: int = 0
    refused_setpoints: int = 0
    takeovers: int = 0
    releases: int = 0
    hand_overs: int = 0      # confirmed ones
    by_client: dict[str, int] = field(default_factory=dict)   # refusals per sender, bounded


@dataclass(frozen=True)
class HandOver:
    """Control offered by ``holder`` to ``target`` until ``until`` (monotonic)."""
    holder: str
    target: str
    until: float
    leaving: bool        # the holder released control naming the target: it is going away


@dataclass(frozen=True)
class Expiry:
    """A holder whose lease ran out: ``released``, or kept because the vehicle may not be left."""
    holder: str
    silent_s: float
    released: bool


class ControlArbiter:
    MAX_CLIENTS = 64      # refusal counts kept per sender (a forger can invent ids: bounded)
    MAX_TOKENS = 256

    def __init__(self, lease_s: float = 5.0) -> None:
        self.lease_s = lease_s
        self.hand_over_s = HAND_OVER_S
        self.holder = ""
        self._holder_seen = 0.0
        self._alive: set[str] = set()       # client ids with a liveliness token
        self._offer: HandOver | None = None
        self._silence_told = False          # the kept holder's silence was reported (once per silence)
        self._lock = threading.Lock()
        self.counters = ControlCounters()

    # -- liveliness ----------------------------------------------------------------
    def token(self, client_id: str, alive: bool) -> None:
        with self._lock:
            if alive and len(self._alive) < self.MAX_TOKENS:
                self._alive.add(client_id)
            elif not alive:
                self._alive.discard(client_id)

    def gone(self, client_id: str, now: float | None = None) -> bool:
        """``client_id`` (the holder) has no token and has been silent for the lease."""
        now = time.monotonic() if now is None else now
        with self._lock:
            return self._gone(client_id, now)

    def _gone(self, client_id: str, now: float) -> bool:
        return client_id not in self._alive and now - self._holder_seen > self.lease_s

    def expire(self, now: float | None = None, *, may_release: bool = True) -> Expiry | None:
        """A holder that is gone: released when ``may_release`` (the vehicle is landed or
        disarmed and no session is open), else kept. Returns what happened, once per silence."""
        now = time.monotonic() if now is None else now
        with self._lock:
            h = self.holder
            if not h or not self._gone(h, now):
                return None
            silent = now - self._holder_seen
            if not may_release:
                if self._silence_told:
                    return None
                self._silence_told = True
                log.warning("control: %s gone (no liveliness token, silent %.1f s): kept, the vehicle is not "
                            "on the ground", h, silent)
                return Expiry(h, silent, False)
            self._set_holder("")
            self.counters.releases += 1
        log.warning("control released: %s gone (no liveliness token, silent %.1f s)", h, silent)
        return Expiry(h, silent, True)

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
                self._renew(now)
                return True, "", ""
            if not h and claim:
                self._set_holder(client_id, now)
                log.info("control: %s takes control (%s)", client_id, what)
                return True, "", ""
            if h and force and claim:
                self._set_holder(client_id, now)
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
                self._renew(time.monotonic())

    def release(self, client_id: str) -> bool:
        with self._lock:
            if self.holder != client_id or not client_id:
                return False
            self._set_holder("")
            self.counters.releases += 1
        log.info("control: %s released control", client_id)
        return True

    # -- hand-over -----------------------------------------------------------------
    @property
    def offer(self) -> HandOver | None:
        return self._offer

    def offer_to(self, client_id: str, target: str, *, leaving: bool = False) -> tuple[bool, str]:
        """The holder offers control to ``target``; it keeps control until ``target`` confirms."""
        with self._lock:
            h = self.holder
            if h != client_id or not client_id:
                why = (f"hand_over refused: {client_id or '<none>'} does not hold control "
                       f"(holder: {h or 'none'})")
            elif not valid_client_id(target):
                why = (f"hand_over refused: the target {target[:64]!r} is not a client id "
                       "(letters, digits, _.@:+-, at most 64)")
            elif target == client_id:
                why = f"hand_over refused: {client_id} already holds control"
            else:
                self._offer = HandOver(h, target, time.monotonic() + self.hand_over_s, leaving)
                self._renew(time.monotonic())
                why = ""
        if why:
            self._refuse(client_id, "hand_over", why)
            return False, why
        log.info("control: %s offers control to %s (%s within %.0f s)", client_id, target,
                 "leaving" if leaving else "staying until confirmed", self.hand_over_s)
        return True, ""

    def accept(self, client_id: str, now: float | None = None) -> str:
        """``client_id`` confirms an offer made to it: it holds control now. Returns the
        previous holder, or "" when there was no such offer (or it expired)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            o = self._offer
            if o is None or o.target != client_id or now > o.until or self.holder != o.holder:
                return ""
            self._set_holder(client_id, now)
            self.counters.hand_overs += 1
        log.warning("control: %s took control from %s (hand-over confirmed)", client_id, o.holder)
        return o.holder

    def expire_offer(self, now: float | None = None) -> HandOver | None:
        """An offer nobody confirmed in time: withdrawn (the holder keeps control) and returned."""
        now = time.monotonic() if now is None else now
        with self._lock:
            o = self._offer
            if o is None or now <= o.until:
                return None
            self._offer = None
        log.warning("control: hand-over from %s to %s not confirmed in time: withdrawn", o.holder, o.target)
        return o

    # -- internals (under the lock) ------------------------------------------------
    def _set_holder(self, client_id: str, now: float = 0.0) -> None:
        self.holder, self._holder_seen = client_id, now
        self._offer = None        # an offer is made by one holder: it ends with its control
        self._silence_told = False

    def _renew(self, now: float) -> None:
        self._holder_seen = now
        self._silence_told = False

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
