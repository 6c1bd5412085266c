"""ControlArbiter rules (pure logic; the Zenoh and PX4 paths are in test_control_lifecycle.py)."""
from __future__ import annotations

import pytest

from companion.control import ControlArbiter
from zenoh_robot.ratelimit import RateLimiter

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def test_first_claim_wins_others_refused_with_the_holder_named() -> None:
    c = ControlArbiter(lease_s=5.0)
    assert c.admit("gcs1", "setpoint")[0] is False          # setpoints never claim
    assert c.admit("gcs1", "offboard_start", claim=True) == (True, "", "")
    ok, why, _ = c.admit("gcs2", "arm", claim=True)
    assert not ok and "gcs1 is in control" in why and "--force" in why
    ok, why, _ = c.admit("gcs2", "take_control", claim=True, force=True)
    assert ok and c.holder == "gcs2"
    assert c.admit("gcs2", "take_control", claim=True, force=True)[0]
    assert c.counters.takeovers == 1 and c.counters.refused_commands == 1


def test_malformed_ids_refused_and_refusal_table_bounded() -> None:
    c = ControlArbiter()
    for bad in ("", "a/b", "x" * 65, "*", "a b"):
        ok, why, _ = c.admit(bad, "arm", claim=True)
        assert not ok and "client_id" in why
    assert c.holder == ""
    c.admit("owner", "arm", claim=True)
    for i in range(500):
        c.admit(f"forger{i}", "setpoint")
    assert len(c.counters.by_client) <= ControlArbiter.MAX_CLIENTS
    assert c.counters.refused_setpoints == 500


def test_holder_released_when_its_token_goes_and_it_falls_silent() -> None:
    c = ControlArbiter(lease_s=1.0)
    c.token("gcs1", True)
    c.admit("gcs1", "offboard_start", claim=True)
    t0 = c._holder_seen
    assert c.expire(t0 + 10.0) is None            # token alive: kept however long it is silent
    c.token("gcs1", False)
    assert c.expire(t0 + 0.5) is None             # within the lease
    gone = c.expire(t0 + 1.5)
    assert gone is not None and gone.released and gone.holder == "gcs1" and c.holder == ""
    c.admit("script", "arm", claim=True)          # no token at all: lives by the lease
    c.seen("script")
    assert c.expire(c._holder_seen + 0.5) is None
    gone = c.expire(c._holder_seen + 1.5)
    assert gone is not None and gone.released and gone.holder == "script"


def test_lease_expiry_in_the_air_keeps_the_holder_and_says_so_once() -> None:
    c = ControlArbiter(lease_s=1.0)
    c.admit("gcs1", "offboard_start", claim=True)
    t0 = c._holder_seen
    kept = c.expire(t0 + 1.5, may_release=False)
    assert kept is not None and not kept.released and kept.holder == "gcs1" and c.holder == "gcs1"
    assert c.expire(t0 + 5.0, may_release=False) is None      # told once per silence
    c.seen("gcs1")                                             # back: a new silence is told again
    assert c.expire(c._holder_seen + 1.5, may_release=False) is not None
    gone = c.expire(t0 + 60.0, may_release=True)               # landed: now it is released
    assert gone is not None and gone.released and c.holder == ""


def test_hand_over_only_to_the_named_client_within_its_time() -> None:
    c = ControlArbiter()
    c.hand_over_s = 1.0
    c.admit("a", "take_control", claim=True)
    assert not c.offer_to("b", "c")[0]                         # only the holder offers
    assert not c.offer_to("a", "a")[0] and not c.offer_to("a", "x y")[0]
    assert c.offer_to("a", "b")[0] and c.holder == "a"          # a keeps control until b confirms
    assert c.accept("c") == "" and c.holder == "a"
    assert c.accept("b") == "a" and c.holder == "b" and c.offer is None
    assert c.counters.hand_overs == 1
    assert c.offer_to("b", "a")[0]
    o = c.offer
    assert o is not None and c.expire_offer(o.until - 0.1) is None
    assert c.expire_offer(o.until + 0.1) == o and c.offer is None
    assert c.accept("a", o.until + 0.2) == "" and c.holder == "b"
    c.offer_to("b", "a")
    c.admit("z", "take_control", claim=True, force=True)       # a forced takeover ends the offer
    assert c.offer is None and c.accept("a") == ""


def test_release_only_by_the_holder() -> None:
    c = ControlArbiter()
    c.admit("gcs1", "take_control", claim=True)
    assert not c.release("gcs2") and c.holder == "gcs1"
    assert c.release("gcs1") and c.holder == ""


def test_rate_limiter_reports_first_then_once_per_interval_with_count() -> None:
    r = RateLimiter(interval=60.0)
    counts = [r.hit("setpoint_rejected", "x", "jump") for _ in range(100)]
    assert counts[0] == 1 and not any(counts[1:])
    assert r.hit("setpoint_rejected", "y", "jump") == 1   # another key reports on its own
