"""One drone id, one vehicle: the GCS never merges two companions' states into one view.

Two companions with one ``--id`` both publish ``<id>/state``; a view fed by both would interleave
two vehicles' positions and steer one from the other's. So a view follows one state publisher at a
time (:class:`StateSource`): another publisher id is followed only once the first has been silent
for ``SWITCH_AFTER_S`` (a companion restart), and one that speaks while the first still does is a
second vehicle: its samples are dropped and counted, and the GCS says so at once. That works on
every transport, multicast included; where liveliness travels, the companions' name claims
(``zenoh_robot.claim``) tell the GCS even before a second state arrives (:func:`watch_claims`).

Threads: ``StateSource.accept`` runs on the executor (the state callback); the claim watch's
callback runs there too (``Node.watch_liveliness``).
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from zenoh_robot import Node
from zenoh_robot.claim import CLAIM_PREFIX, claim_namespace, claim_scope, parse_claim

SWITCH_AFTER_S = 2.0    # states come at 5 Hz: 10 missed states is a companion that stopped, not a jitter
MAX_OTHERS = 16         # publisher ids remembered per drone (bounded: a peer chooses them)
MAX_CLAIMED = 1000      # drone ids whose claims are followed


class StateSource:
    """Which companion's state a drone's view follows (the module doc)."""

    def __init__(self, on_second: Callable[[str], None]) -> None:
        self.publisher: int | None = None
        self._last = 0.0
        self._others: OrderedDict[int, float] = OrderedDict()
        self._on_second = on_second
        self.ignored = 0

    def accept(self, publisher_id: int, now: float) -> bool:
        """True: the view takes this state; False: another vehicle's, dropped (and reported when new)."""
        if publisher_id == self.publisher or self.publisher is None or now - self._last > SWITCH_AFTER_S:
            self.publisher, self._last = publisher_id, now
            self._others.pop(publisher_id, None)
            return True
        self.ignored += 1
        new = publisher_id not in self._others
        self._others[publisher_id] = now
        self._others.move_to_end(publisher_id)
        while len(self._others) > MAX_OTHERS:
            self._others.popitem(last=False)
        if new:
            self._on_second(f"two companions publish this drone's state (publisher {self.publisher:#x} followed, "
                            f"{publisher_id:#x} ignored): one id, two vehicles")
        return False

    def duplicated(self, now: float) -> bool:
        """Another publisher spoke within the last ``SWITCH_AFTER_S``."""
        return any(now - t <= SWITCH_AFTER_S for t in self._others.values())


def watch_claims(node: Node, on_change: Callable[[str, list[str]], None]) -> Any:
    """``on_change(drone_id, zids)`` on the executor whenever the sessions holding ``/<id>/companion`` change;
    two or more zids: two companions claim one id. Returns the watch, to undeclare."""
    held: dict[str, dict[str, bool]] = {}

    def on_token(key: str, alive: bool) -> None:
        try:
            claim = parse_claim(key)
        except ValueError:
            return
        drone = claim_namespace(key)
        if not claim.held or (drone not in held and len(held) >= MAX_CLAIMED):
            return
        zids = held.setdefault(drone, {})
        if alive:
            zids[claim.zid] = True
        else:
            zids.pop(claim.zid, None)
        on_change(drone, sorted(zids))
    return node.watch_liveliness(f"{CLAIM_PREFIX}/{claim_scope(node.wire.graph)}/*/companion/*/*/*", on_token)
