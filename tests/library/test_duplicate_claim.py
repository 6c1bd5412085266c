"""One name, one process (issue #42, part 3): a second ``/<id>/companion`` is refused at start, or told
to yield at once if it got through, whatever order the sessions start in, peer or via a router.

The reproduction: many short start-ups of two claimants of one name and the sessions around them,
in-process on loopback. Before the claim (zenoh_robot/claim.py), a liveliness query right after the
session opened decided alone; it is answered before routing or peer discovery delivers the other's
token, and both claimants ran in 40 of 120 start-ups (20 per order; 20 of them where the two can only
meet after both started, "router_last"). With the claim: 0 of 120 (95 refused at start, 25 told to
yield once they met). ``ZR_CLAIM_ROUNDS`` repeats every start-up order that many times (default 2).
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import pytest
from conftest import free_port, wait_for

from zenoh_robot import Node, SessionConfig
from zenoh_robot.claim import Claim, parse_claim
from zenoh_robot.events import DuplicateNodeInfo
from zenoh_robot.graph import DuplicateNodeError

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

ROUNDS = int(os.environ.get("ZR_CLAIM_ROUNDS", "2"))


def _config(listen: list[str], connect: list[str], mode: str = "peer") -> SessionConfig:
    return SessionConfig(mode=mode, listen=listen, connect=connect, multicast_scouting=False, shared_memory=False)


def _tcp() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@dataclass
class Claimant:
    label: str
    node: Node | None = None
    refused: str = ""
    verdicts: list[DuplicateNodeInfo] = field(default_factory=list)
    thread: threading.Thread | None = None

    def start(self, name: str, ns: str, config: SessionConfig) -> None:
        try:
            node = Node(name, namespace=ns, config=config, settle_name=True)
        except DuplicateNodeError as exc:
            self.refused = str(exc)
            return
        node.claim.on_duplicate(self.verdicts.append)
        self.thread = threading.Thread(target=node.spin, daemon=True)
        self.thread.start()
        self.node = node

    @property
    def yielded(self) -> bool:
        return any(v.alive and v.yields for v in self.verdicts)

    @property
    def survives(self) -> bool:
        return self.node is not None and not self.yielded

    def close(self) -> None:
        if self.node is not None:
            self.node.close()
        if self.thread is not None:
            self.thread.join(timeout=2.0)


# Each start-up order: (name, run) where run(ns, a, b) starts the sessions around the two claimants and
# the claimants themselves, returning the helper nodes to close; ``a`` starts (or starts first) wherever
# the order says "first", so an established ``a`` must be the one that keeps the name.
Order = Callable[[str, Claimant, Claimant], list[Node]]


def _direct(ns: str, a: Claimant, b: Claimant) -> list[Node]:
    port = _tcp()
    a.start("companion", ns, _config([port], []))
    b.start("companion", ns, _config([_tcp()], [port]))
    return []


def _via_hub_peer(ns: str, a: Claimant, b: Claimant) -> list[Node]:
    # The claimants meet only through gossip: the hub peer routes nothing between them.
    hub_at = _tcp()
    hub = Node("hub", namespace=ns, config=_config([hub_at], []))
    a.start("companion", ns, _config([_tcp()], [hub_at]))
    b.start("companion", ns, _config([_tcp()], [hub_at]))
    return [hub]


def _via_router(mode: str) -> Order:
    def order(ns: str, a: Claimant, b: Claimant) -> list[Node]:
        at = _tcp()
        router = Node("router", namespace=ns, config=_config([at], [], mode="router"))
        listen = [_tcp()] if mode == "peer" else []
        a.start("companion", ns, _config(listen, [at], mode=mode))
        b.start("companion", ns, _config([_tcp()] if mode == "peer" else [], [at], mode=mode))
        return [router]
    return order


def _router_comes_last(ns: str, a: Claimant, b: Claimant) -> list[Node]:
    # Both claimants start alone (their router is not up: each retries), so neither can see the other
    # at start; they meet when the router comes, and the later start must yield.
    at = _tcp()
    a.start("companion", ns, _config([_tcp()], [at]))
    b.start("companion", ns, _config([_tcp()], [at]))
    return [Node("router", namespace=ns, config=_config([at], [], mode="router"))]


def _together(ns: str, a: Claimant, b: Claimant) -> list[Node]:
    port = _tcp()
    threads = [threading.Thread(target=c.start, args=("companion", ns, conf))
               for c, conf in ((a, _config([port], [])), (b, _config([_tcp()], [port])))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return []


ORDERS: dict[str, tuple[Order, bool]] = {   # name: (start-up, whether ``a`` is sure to be the earlier claim)
    "direct": (_direct, True),
    "hub_peer": (_via_hub_peer, True),
    "router_peers": (_via_router("peer"), True),
    "router_clients": (_via_router("client"), True),
    "router_last": (_router_comes_last, True),
    "together": (_together, False),
}


@contextmanager
def _startup(order: Order, ns: str) -> Iterator[tuple[Claimant, Claimant]]:
    a, b = Claimant("a"), Claimant("b")
    helpers: list[Node] = []
    try:
        helpers = order(ns, a, b)
        yield a, b
    finally:
        for c in (b, a):
            c.close()
        for h in helpers:
            h.close()


def _outcome(a: Claimant, b: Claimant) -> str:
    """Once both have met: "refused" (one never started), "yielded" (one was told to stop), or "both run"."""
    if a.refused or b.refused:
        return "refused"
    assert a.node is not None and b.node is not None
    met = wait_for(lambda: a.yielded or b.yielded, 8.0)
    return "yielded" if met else "both run"


@pytest.mark.parametrize("order_name", sorted(ORDERS))
def test_a_name_is_held_by_one_process_whatever_the_start_up_order(order_name: str, ns: str) -> None:
    order, a_first = ORDERS[order_name]
    outcomes = []
    for i in range(ROUNDS):
        with _startup(order, f"{ns}r{i}") as (a, b):
            outcome = _outcome(a, b)
            outcomes.append(outcome)
            assert outcome != "both run", f"{order_name}: two processes hold /{ns}r{i}/companion ({outcomes})"
            survivors = [c for c in (a, b) if c.survives]
            assert len(survivors) == 1, (order_name, outcome, a, b)
            if a_first:
                assert survivors[0] is a, f"{order_name}: the later start kept the name ({a}, {b})"
            if outcome == "yielded":   # both sides were told, with the same verdict
                keeper = survivors[0]
                assert wait_for(lambda k=keeper: any(v.alive and not v.yields for v in k.verdicts), 5.0), keeper
            else:
                assert "/companion is " in (a.refused or b.refused)


def test_a_refused_claimant_leaves_no_claim_and_the_name_is_free_after_the_holder_closes(ns: str) -> None:
    port = _tcp()
    first = Node("companion", namespace=ns, config=_config([port], []), settle_name=True)
    try:
        with pytest.raises(DuplicateNodeError, match=f"/{ns}/companion is already running"):
            Node("companion", namespace=ns, config=_config([_tcp()], [port]), settle_name=True)
        second = Node("companion2", namespace=ns, config=_config([_tcp()], [port]))    # another name is fine
        second.close()
        assert first.claim.rivals() == []
    finally:
        first.close()
    again = Node("companion", namespace=ns, config=_config([port], []), settle_name=True)
    again.close()


def test_a_second_holder_that_goes_away_is_reported_gone(ns: str) -> None:
    at = _tcp()
    a, b = Claimant("a"), Claimant("b")
    a.start("companion", ns, _config([_tcp()], [at]))
    b.start("companion", ns, _config([_tcp()], [at]))
    router = Node("router", namespace=ns, config=_config([at], [], mode="router"))
    try:
        assert wait_for(lambda: b.yielded, 10.0), b
        b.close()
        assert wait_for(lambda: any(not v.alive for v in a.verdicts), 10.0), a.verdicts
        assert a.node is not None and a.node.claim.rivals() == []
    finally:
        a.close()
        b.close()
        router.close()


def test_claim_keys_round_trip_and_foreign_keys_are_refused() -> None:
    from zenoh_robot.claim import claim_key, claim_namespace, claim_scope, claim_selector
    from zenoh_robot.wire import ENVELOPE, ros2_wire
    scope = claim_scope(ENVELOPE.graph)
    assert scope == "zr%lv" and claim_scope(ros2_wire(3).graph) != scope    # one world per graph format
    c = Claim("abc123", 1_700_000_000_000_000_000, True)
    key = claim_key(scope, "uav1/x", "companion", c)
    assert parse_claim(key) == c and key.startswith("@zr/claim/zr%lv/uav1%x/companion/")
    assert claim_namespace(key) == "uav1/x"
    assert claim_selector(scope, "", "gcs") == "@zr/claim/zr%lv/%/gcs/*/*/*"
    for bad in ("@zr/claim/s/a/b/c", "@zr/claim/s/a/b/z/notanumber/h", "@zr/claim/s/a/b/z/1/x"):
        with pytest.raises(ValueError):
            parse_claim(bad)
