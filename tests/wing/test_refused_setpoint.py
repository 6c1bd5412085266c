"""A refused setpoint is counted and its sender hears why (issue #24, item 7): a NaN or an
infinite value from the GCS in control, also after a peer has filled the reporter's table with
forged client ids. In-process with real parts: the simulator over MAVLink/UDP, px4_link, the
Companion on a real Zenoh session, test peers on another."""
from __future__ import annotations

import math
import time

from conftest import wait_for
from rigs import Client, rig

from drone_contract.messages import DroneSetpoint
from zenoh_robot.msgs import Header

NAN = float("nan")


def _refusals_to(c: Client, client_id: str, needle: str) -> list[str]:
    return [e.detail for e in list(c.events)
            if e.kind == "setpoint_rejected" and e.client_id == client_id and needle in e.detail]


def _take_control(c: Client) -> None:
    c.target = (0.0, 0.0, -2.0)       # a GCS streams before it asks
    time.sleep(0.4)
    res = c.command("take_control")
    assert res.success, res.message   # it keeps streaming valid setpoints: it stays in control


def test_a_nan_setpoint_from_the_holder_is_counted_and_reported_to_it(ns: str) -> None:
    with rig(ns, report_interval_s=0.2) as r:   # each refusal its own event, not one per 2 s
        _take_control(r.op)
        gate = r.companion.gate
        # One at a time, with op's own stream paused (its token keeps control): the setpoint subscription keeps
        # only the newest sample, so two in one drain would count as one (the older superseded, never judged).
        r.op.target = None
        for i in range(1, 4):
            r.op.pub.publish(DroneSetpoint(Header.now(), r.op.client_id, NAN, 0.0, -2.0))
            assert wait_for(lambda: gate.rejected_by_reason["non_finite"] == i, 5), (i, gate.rejected_by_reason)  # noqa: B023
        assert wait_for(lambda: _refusals_to(r.op, "op", "non-finite"), 5), r.op.events
        # An infinite yaw is no heading: refused as well, not flown with the heading dropped.
        time.sleep(0.3)
        r.op.pub.publish(DroneSetpoint(Header.now(), r.op.client_id, 0.0, 0.0, -2.0, math.inf))
        assert wait_for(lambda: gate.rejected_by_reason["non_finite"] == 4, 5), gate.rejected_by_reason
        assert wait_for(lambda: any("yaw=inf" in d for d in _refusals_to(r.op, "op", "non-finite")), 5), \
            r.op.events


def test_the_holder_still_hears_after_a_peer_filled_the_reporter_with_forged_ids(ns: str) -> None:
    """The refusal reporter's table of (kind, client, reason) is bounded and never evicts a live window (so a
    forger gains no fresh budget); once a flood of invented client ids fills it, a new key is
    counted but never reported. The GCS in control must still hear of its refused setpoints."""
    with rig(ns) as r:
        _take_control(r.op)
        limiter = r.companion.events.limiter
        forger = r.other.pub
        deadline = time.monotonic() + 30
        i = 0
        while limiter.overflow == 0 and time.monotonic() < deadline:
            forger.publish(DroneSetpoint(Header.now(), f"forged{i}", 0.0, 0.0, -2.0))
            i += 1
            time.sleep(0.002)
        assert limiter.overflow > 0, f"the table never filled ({i} forged ids sent)"
        r.op.pub.publish(DroneSetpoint(Header.now(), r.op.client_id, NAN, 0.0, -2.0))
        assert wait_for(lambda: _refusals_to(r.op, "op", "non-finite"), 5), \
            f"no word to the holder; events to it: {[e.kind for e in r.op.events if e.client_id == 'op']}"
        assert r.companion.gate.rejected_by_reason["non_finite"] == 1
