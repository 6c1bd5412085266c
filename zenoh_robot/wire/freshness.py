"""Freshness of sealed samples across restarts: the drone's own clock, echoed by whoever talks to it.

A seal's replay window (``wire/sealed.py``) lives in memory, so on its own a capture replayed after
the receiver restarted opens again. Every sealed sample therefore names *which start of its scope's
owner* it was sealed for, and *when* on that owner's clock: ``(boot, ms)`` in the seal's head, covered
by the tag. The owner of a scope is the drone whose namespace it is (``uav1`` owns ``uav1/...`` and
``@srv/uav1/...``: its setpoints, presence, commands and parameters, everything that can move it).

- The owner numbers its starts (``boot``: one more than the last start's, persisted beside its keyring,
  never lower than the wall clock's seconds) and counts milliseconds from its start (``ms``, on the
  monotonic clock). It stamps its own samples with both.
- Everyone else learns the owner's ``(boot, ms)`` from the owner's own sealed samples (its telemetry,
  its replies), keeps the freshest lower bound of the owner's clock (:class:`ScopeClocks`: the largest
  ``ms`` seen, extrapolated with the local monotonic clock), and stamps what it seals in that scope with
  it. A sender that never heard the owner stamps ``boot`` 0 (unbound).
- The owner refuses a sample or a call sealed by another key unless it names its current boot (else
  ``restarted``: recorded before this start; ``unbound``: its sender had not heard this start) and is
  at most ``fresh_s`` old on its own clock (else ``expired``). Others check what they receive against
  what they learnt (older boot: ``restarted``; older than ``fresh_s``: ``expired``).

Why this and not MAVLink 2 signing's timestamp or a handshake: no clock the field lacks (only each
node's monotonic clock, never compared with another's wall clock), no round trip before the first
setpoint (the GCS hears the drone's telemetry before it flies it, and a restarted drone's next
telemetry sample re-binds the GCS at once, at any loss the telemetry survives), one-to-many as
multicast is (every receiver of a scope checks the same stamp), and 8 bytes a sample. A capture
replayed after the owner restarted names an old boot; one replayed later than ``fresh_s`` is
expired; one replayed sooner meets the replay window, which the owner has kept since its start.

Threading: :class:`ScopeClocks` is shared by a node's sealers and openers (publishers' threads, the
executor, Zenoh's threads): one lock around a small dict; the hot path reads one tuple.
"""
from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path

log = logging.getLogger(__name__)

FRESH_S = 5.0         # the freshness bound: a sealed sample older than this on its owner's clock is refused
FUTURE_S = 2.0        # how far ahead of the owner's clock a stamp may be (an estimate only lags; drift aside)
REANCHOR_S = 60.0     # an estimate older than this follows a fresh sample slightly behind it (clock drift) ...
REANCHOR_BEHIND_MS = 250    # ... at most this far behind (a replay a few seconds old never pulls it back)
UNBOUND = 0           # the boot a sender stamps when it never heard the scope's owner
_WRAP = 1 << 32
_HALF = 1 << 31
_CLOCKS: dict[Path, OwnClock] = {}  # one clock per node per process (a second session of the same node shares it)
_BOOTS_LOCK = threading.Lock()


def age_ms(now_ms: int, stamp_ms: int) -> int:
    """``now_ms - stamp_ms`` on a 32-bit millisecond clock (negative: the stamp is ahead)."""
    d = (now_ms - stamp_ms) & (_WRAP - 1)
    return d - _WRAP if d >= _HALF else d


def own_clock(path: Path) -> OwnClock:
    """This process's clock as the owner whose start counter is ``path``: its boot is one more than the
    stored one, at least the wall clock's seconds (a lost file on a machine with a clock still goes up),
    stored before it is used. Unwritable: the wall clock alone, said once (a clock reset then reopens
    old captures). Cached per path, so every session of a node in one process shares it."""
    path = Path(path)
    with _BOOTS_LOCK:
        cached = _CLOCKS.get(path)
        if cached is not None:
            return cached
        try:
            stored = int(path.read_text().strip() or 0)
        except FileNotFoundError:
            stored = 0
        except (OSError, ValueError) as exc:
            log.warning("sealed: boot counter %s unreadable (%s): starting from the wall clock", path, exc)
            stored = 0
        boot = min(max(stored + 1, int(time.time())), _WRAP - 1)
        try:
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
            with open(tmp, "w") as f:
                f.write(f"{boot}\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except OSError as exc:
            log.warning("sealed: cannot store the boot counter %s (%s): captures from before a restart are "
                        "refused only while this machine's clock keeps going forward", path, exc)
        clock = _CLOCKS[path] = OwnClock(boot)
        return clock


class OwnClock:
    """The owner's stamp: its boot number and milliseconds since this start (monotonic)."""
    __slots__ = ("boot", "_t0")

    def __init__(self, boot: int) -> None:
        if not 0 < boot < _WRAP:
            raise ValueError(f"boot number {boot} out of range")
        self.boot = boot
        self._t0 = time.monotonic()

    def now_ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000.0) & (_WRAP - 1)

    def check(self, boot: int, stamp_ms: int, fresh_s: float) -> str | None:
        """Why a sample another key sealed in this owner's scope is not fresh, or None."""
        if boot != self.boot:
            return "unbound" if boot == UNBOUND else "restarted"
        age = age_ms(self.now_ms(), stamp_ms)
        if age > fresh_s * 1000.0 or age < -FUTURE_S * 1000.0:
            return "expired"
        return None


class ScopeClocks:
    """What a node knows of each scope owner's clock: ``scope -> (boot, ms, local monotonic when)``.
    Moved only by the owner's own authentic samples, and only forward (a newer boot, or a stamp ahead
    of the extrapolated estimate), so a replayed old sample can never pull it back."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._known: dict[str, tuple[int, int, float]] = {}

    def estimate(self, scope: str) -> tuple[int, int]:
        """``(boot, ms)`` to stamp a sample in ``scope`` with; ``(UNBOUND, 0)`` if its owner was never heard."""
        known = self._known.get(scope)
        if known is None:
            return UNBOUND, 0
        boot, ms, at = known
        return boot, (ms + int((time.monotonic() - at) * 1000.0)) & (_WRAP - 1)

    def check(self, scope: str, boot: int, stamp_ms: int, fresh_s: float) -> str | None:
        """Why a sample in ``scope`` is older than what this node knows of its owner, or None."""
        if boot == UNBOUND or scope not in self._known:
            return None
        known_boot, now_ms = self.estimate(scope)
        if boot < known_boot:
            return "restarted"
        if boot == known_boot and age_ms(now_ms, stamp_ms) > fresh_s * 1000.0:
            return "expired"
        return None

    def learn(self, scope: str, boot: int, stamp_ms: int) -> None:
        """The owner of ``scope`` sealed a sample stamped ``(boot, stamp_ms)`` (already checked fresh)."""
        if boot == UNBOUND:
            return
        now = time.monotonic()
        with self._lock:
            known = self._known.get(scope)
            if known is not None and boot < known[0]:
                return
            if known is not None and boot == known[0]:
                ahead = age_ms(stamp_ms, (known[1] + int((now - known[2]) * 1000.0)) & (_WRAP - 1))
                if ahead <= 0 and (now - known[2] < REANCHOR_S or ahead < -REANCHOR_BEHIND_MS):
                    return
            self._known[scope] = (boot, stamp_ms, now)

    def known(self) -> dict[str, int]:
        """``scope -> boot`` of every owner heard (for summaries)."""
        with self._lock:
            return {scope: k[0] for scope, k in self._known.items()}
