"""A node's claim on its fully qualified name: one process per name in a domain, checked at start, watched after.

Why not one liveliness query at start (what ``graph.ensure_unique_node`` did alone): a query sent
right after the session opens is answered at once, before routing or peer discovery has delivered
the other sessions' tokens. Measured on loopback (issue #42), through a router, a hub peer or a
client link: the query returned no reply, 2-20 ms after ``open``, in 11 of 12 tries, while a
liveliness subscriber with history saw the running node's token 1-120 ms after ``open``. A second
``/uav1/companion`` started in 20 of 100 start-ups (tests/library/test_duplicate_claim.py's orders,
20 each: through a router 9, a hub peer 5, both at once 6, direct link or router clients 0), and in
20 of 20 where the two met only after both had started (their router came last).

So a claim is a liveliness token of its own, declared before anything is decided::

    @zr/claim/<scope>/<ns>/<node>/<zid>/<since_ns>/<s|h>      s: starting, h: held

``<scope>`` is the node's graph format's (its graph selector: ``zr%lv`` for the envelope format,
``ros2_lv%<domain>`` for ROS 2's): nodes of different formats neither hear nor see each other, so
one name in each is no duplicate (the companion's ROS 2 node beside its own, ``--ros2-topics``).

1. Declare the *starting* token and subscribe (with history) to every claim on the name.
2. Settle: wait until no claim and no new transport has come for ``QUIET_S`` (a new peer's
   tokens follow its transport by milliseconds), at most ``MAX_SETTLE_S``.
3. Refuse (:class:`~zenoh_robot.graph.DuplicateNodeError`) if another session holds the name, or is
   starting too and ranks first; else declare the *held* token and withdraw the starting one.
4. Keep watching. A held claim of another session that appears later (a partition heals, a link
   came up after the settle window) is a :class:`DuplicateNodeInfo` on both sides, delivered on the
   node's executor, with the same verdict on both: the earlier ``since`` (then the smaller zid) keeps
   the name, the other ``yields`` and should stop. Without a listener it is logged as an error.

A held claim always beats a starting one, whatever the clocks say, so a running node is never
told to yield to a newcomer; only two held claims (two networks joined) are ranked by their wall
clock stamps, which must then be roughly in step for "earlier" to mean earlier (the verdict is the
same on both sides either way). Claims travel as liveliness tokens: on a UDP multicast session
(``SessionConfig.resilient``) Zenoh 1.10 carries none, so there is nothing to settle or watch.

Threads: Zenoh's callback only parses the key and updates a bounded table; listeners run on the
executor.
"""
from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import zenoh

from .events import DuplicateNodeInfo
from .graph import DuplicateNodeError
from .session_config import is_multicast_session

if TYPE_CHECKING:
    from .wire.format import GraphFormat

log = logging.getLogger("zenoh_robot.claim")

CLAIM_PREFIX = "@zr/claim"
STARTING, HELD = "s", "h"
QUIET_S = 0.25         # no new claim nor transport this long: what the network had to say has arrived
MAX_SETTLE_S = 2.0     # a network that keeps changing does not hold a start for longer
POLL_S = 0.05          # transports are polled (Zenoh reports no new one by callback)
MAX_CLAIMS = 64        # claim keys kept per name: a peer chooses them, so the table is bounded

DuplicateListener = Callable[[DuplicateNodeInfo], None]


class _Executor(Protocol):
    def call_soon(self, fn: Callable[[], None]) -> bool: ...


@dataclass(frozen=True)
class Claim:
    zid: str
    since_ns: int
    held: bool

    @property
    def rank(self) -> tuple[int, str]:
        return self.since_ns, self.zid


def _mangle(text: str) -> str:
    return text.replace("/", "%") if text else "%"


def claim_scope(graph_format: GraphFormat) -> str:
    """One key chunk naming a graph format's world (the module doc)."""
    return _mangle(graph_format.selector.removesuffix("/**").lstrip("@"))


def claim_selector(scope: str, namespace: str, node_name: str) -> str:
    return "/".join([CLAIM_PREFIX, scope, _mangle(namespace), node_name, "*", "*", "*"])


def claim_key(scope: str, namespace: str, node_name: str, claim: Claim) -> str:
    return "/".join([CLAIM_PREFIX, scope, _mangle(namespace), node_name, claim.zid, str(claim.since_ns),
                     HELD if claim.held else STARTING])


def parse_claim(key: str) -> Claim:
    """ValueError for a key not in the claim format."""
    parts = key.split("/")
    if len(parts) != 8 or parts[7] not in (STARTING, HELD) or not parts[6].isdigit():
        raise ValueError(f"not a claim: {key!r}")
    return Claim(parts[5], int(parts[6]), parts[7] == HELD)


def claim_namespace(key: str) -> str:
    """The namespace a claim key names (no leading ``/``; ``""``: the root)."""
    ns = key.split("/")[3]
    return "" if ns == "%" else ns.replace("%", "/")


def transport_zids(session: zenoh.Session) -> set[str]:
    try:
        return {str(t.zid) for t in session.info.transports()}
    except Exception:     # a closing session has none
        return set()


class NodeClaim:
    """This node's claim on ``/<namespace>/<node_name>`` (the module doc). :meth:`start` settles and
    decides; :meth:`on_duplicate` registers a listener for later claimants."""

    def __init__(self, session: zenoh.Session, scope: str, namespace: str, node_name: str, executor: _Executor,
                 fqn: str) -> None:
        self._session = session
        self._scope, self._namespace, self._name, self.fqn = scope, namespace, node_name, fqn
        self._executor = executor
        self.own = Claim(str(session.info.zid()), time.time_ns(), False)
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._changes = 0
        self._keys: dict[str, Claim] = {}      # other sessions' claim keys alive now
        self._rivals: set[str] = set()         # zids already reported as holding the name too
        self._held = False
        self._closed = False
        self.refused_keys = 0                  # claim keys past MAX_CLAIMS: not kept, counted
        self.listeners: list[DuplicateListener] = []
        self._tokens: list[Any] = [session.liveliness().declare_token(claim_key(scope, namespace, node_name,
                                                                                self.own))]
        try:
            self._sub = session.liveliness().declare_subscriber(claim_selector(scope, namespace, node_name),
                                                                self._on_token, history=True)
        except BaseException:
            self._undeclare_tokens()
            raise

    # -- start-up ------------------------------------------------------------------------
    def start(self, quiet_s: float = QUIET_S, max_settle_s: float = MAX_SETTLE_S) -> None:
        """Settle, then hold the name or raise DuplicateNodeError (the caller closes the session)."""
        self._settle(quiet_s, max_settle_s)
        first = self._first_rival()
        if first is not None:
            how = "is already running" if first.held else "is starting at the same time, first,"
            raise DuplicateNodeError(f"node {self.fqn} {how} in this domain (zid {first.zid}"
                                     f"{self._where(first.zid)}): stop it, or give this one another name/namespace "
                                     "or --domain")
        held = Claim(self.own.zid, self.own.since_ns, True)
        self._tokens.append(self._session.liveliness().declare_token(
            claim_key(self._scope, self._namespace, self._name, held)))
        starting = self._tokens.pop(0)
        starting.undeclare()
        with self._lock:
            self.own, self._held = held, True
        self._report()      # a rival that became held during the hand-over is not missed

    def _settle(self, quiet_s: float, max_settle_s: float) -> None:
        # The CLI's settled listings (tools/cli/topic.py, discover_graph) use the same rule: a quiet spell,
        # restarted by every new claim and by every new transport (its tokens follow it by milliseconds).
        now = time.monotonic()
        end, quiet_from = now + max_settle_s, now
        peers = transport_zids(self._session)
        with self._lock:
            seen = self._changes
        while now < end and now - quiet_from < quiet_s:
            with self._lock:
                if self._changes == seen:
                    self._changed.wait(min(POLL_S, end - now))
                if self._changes != seen:
                    seen, quiet_from = self._changes, time.monotonic()
            current = transport_zids(self._session)
            now = time.monotonic()
            if not current <= peers:
                quiet_from = now
            peers = current

    def _first_rival(self) -> Claim | None:
        """The claim that keeps the name against this starting one, if any: held first, then the first ranked."""
        with self._lock:
            others = list(self._by_zid().values())
        held = [c for c in others if c.held]
        if held:
            return min(held, key=lambda c: c.rank)
        earlier = [c for c in others if c.rank < self.own.rank]
        return min(earlier, key=lambda c: c.rank) if earlier else None

    def _where(self, zid: str) -> str:
        try:
            for link in self._session.info.links():
                if str(link.zid) == zid:
                    return f" at {link.dst}"
        except Exception:
            pass
        return ", via another peer or a router"

    # -- watching (Zenoh's thread) -----------------------------------------------------------
    def _on_token(self, sample: Any) -> None:
        key = str(sample.key_expr)
        try:
            claim = parse_claim(key)
        except ValueError:
            return
        if claim.zid == self.own.zid:
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            if self._closed or alive == (key in self._keys):
                return
            if alive:
                if len(self._keys) >= MAX_CLAIMS:
                    self.refused_keys += 1
                    return
                self._keys[key] = claim
            else:
                del self._keys[key]
            self._changes += 1
            self._changed.notify_all()
            held = self._held
        if held:
            self._report()

    def _by_zid(self) -> dict[str, Claim]:
        """One claim per other session, held if any of its keys is (a hand-over briefly shows both)."""
        out: dict[str, Claim] = {}
        for c in self._keys.values():
            if c.zid not in out or c.held:
                out[c.zid] = c
        return out

    def _report(self) -> None:
        """Hand the changes of the rival set (other sessions holding the name) to the executor."""
        with self._lock:
            if self._closed or not self._held:
                return
            holders = {z: c for z, c in self._by_zid().items() if c.held}
            came = [holders[z] for z in sorted(holders.keys() - self._rivals)]
            went = sorted(self._rivals - holders.keys())
            self._rivals = set(holders)
            own = self.own
        for c in came:
            self._fire(DuplicateNodeInfo(self.fqn, c.zid, c.since_ns, own.rank > c.rank, True))
        for zid in went:
            self._fire(DuplicateNodeInfo(self.fqn, zid, 0, False, False))

    def _fire(self, info: DuplicateNodeInfo) -> None:
        if not self._executor.call_soon(lambda: self._deliver(info)):
            log.error("%s: duplicate-name event dropped (executor queue full): %s", self.fqn, info.describe())

    def _deliver(self, info: DuplicateNodeInfo) -> None:   # the executor
        listeners = list(self.listeners)
        if not listeners:
            (log.error if info.alive else log.warning)("%s", info.describe())
        for listener in listeners:
            try:
                listener(info)
            except Exception:
                log.exception("duplicate-name listener of %s failed", self.fqn)

    # -- API ---------------------------------------------------------------------------------
    def on_duplicate(self, listener: DuplicateListener) -> None:
        """``listener(DuplicateNodeInfo)`` on the executor when another session comes to hold this name too,
        and again (``alive`` False) when it stops; a rival already known is reported at once."""
        with self._lock:
            self.listeners.append(listener)
            rivals = [c for z, c in self._by_zid().items() if z in self._rivals]
            own = self.own
        for c in rivals:
            info = DuplicateNodeInfo(self.fqn, c.zid, c.since_ns, own.rank > c.rank, True)
            self._executor.call_soon(functools.partial(listener, info))

    def rivals(self) -> list[str]:
        """Zenoh ids of the other sessions holding this name now."""
        with self._lock:
            return sorted(self._rivals)

    def _undeclare_tokens(self) -> None:
        tokens, self._tokens = self._tokens, []
        for token in tokens:
            try:
                token.undeclare()
            except zenoh.ZError as exc:   # the session may already be closing
                log.debug("claim token: %s", exc)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:
            self._sub.undeclare()
        except zenoh.ZError as exc:
            log.debug("claim watch: %s", exc)
        self._undeclare_tokens()


def start_claim(session: zenoh.Session, graph_format: GraphFormat, namespace: str, node_name: str,
                executor: _Executor, fqn: str, settle: bool = True) -> NodeClaim:
    """Claim the name, settling first if asked (never on a multicast session: no token crosses it);
    DuplicateNodeError if taken. Without ``settle`` the start decides on what this session knows at once
    (what ``ensure_unique_node`` did) and the watch raises a rival heard later: every node pays the
    settle's 0.25 s otherwise, a CLI command and each of the test suite's thousands of nodes among them."""
    claim = NodeClaim(session, claim_scope(graph_format), namespace, node_name, executor, fqn)
    try:
        if not settle or is_multicast_session(session):
            claim.start(0.0, 0.0)
        else:
            claim.start()
    except BaseException:
        claim.close()
        raise
    return claim
