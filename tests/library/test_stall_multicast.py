"""The resilient streams must never stall on the multicast transport (docs/zenoh-multicast-stall.md).

Zenoh 1.10's UDP multicast transport stops sending for good when express samples go out in
quick succession (a setpoint and its 3 ms repeats), more often when other processes load the
CPU. The stall hit a run now and then, so one run proves nothing: this test runs many short
GCS <-> drone pairs at once (each pair in its own namespaces, joined by a veth with no loss),
under two busy-looping CPU hogs, and asserts that every stream delivered to the end.

The pair runner is ``drone_lab.experiment.stall_runs`` (which also runs 50 consecutive
runs from the command line: docs/results/stall_runs.md). Each pair runs what the ``resilient``
profile runs on one session: LossMonitor probes from their own thread, the GCS's setpoint copies
following the fed-back loss, the drone's paced FEC image bursts; three threads put concurrently
on each multicast session. With ``ZR_STALL_EXPRESS=1`` the GCS's setpoints go out with express
(the old setting, forced past the library's workaround): then the test fails in most runs.
"""
from __future__ import annotations

import os

import pytest

from drone_lab.experiment.stall_runs import cpu_hogs, run_pairs, setpoint_gaps_ms

RUNS = 8            # at once: the stall needs load, and the runs are part of it
SECONDS = 4.0


def test_setpoint_gaps_include_the_window_edges() -> None:
    ms = 1_000_000
    # Regular arrivals: the gaps are the period; a copy that arrives after the window is ignored.
    assert setpoint_gaps_ms(0, 300 * ms, [0, 100 * ms, 200 * ms, 300 * ms, 900 * ms]) == [0.0, 100.0, 100.0, 100.0, 0.0]
    # A stream that stopped after 100 ms ends in one long gap up to the last send.
    assert max(setpoint_gaps_ms(0, 4000 * ms, [10 * ms, 100 * ms])) == 3900.0
    # Nothing at all: the whole window is one gap.
    assert setpoint_gaps_ms(0, 4000 * ms, []) == [4000.0]


@pytest.mark.netns
def test_resilient_streams_with_loss_feedback_never_stall_on_multicast_under_cpu_load() -> None:
    import zfec  # noqa: F401  (the [image] extra, in dev: missing is a failure)
    from conftest import skip_unless_required

    from drone_lab.experiment.netns import unavailable_reason

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"multicast stall test: network namespaces are unavailable: {reason}")
    with cpu_hogs(2):
        results = run_pairs(RUNS, SECONDS)
    assert not [r.error for r in results if r.error], results
    if os.environ.get("ZR_STALL_EXPRESS") != "1":
        assert not any(r.express_on_wire for r in results), "express reached a multicast session"
    stalled = [(r.sent, r.unique, r.last) for r in results if r.setpoint_stalled]
    assert not stalled, f"{len(stalled)}/{RUNS} setpoint streams stalled (sent, received, last): {stalled}"
    blind = [(r.frames_sent, r.frames, r.last_frame) for r in results if r.image_stalled]
    assert not blind, f"{len(blind)}/{RUNS} FEC image streams stalled (sent, received, last): {blind}"
    # Not asserted: every gap under PX4's 500 ms. Under two hogs 2 of 50 runs had one ~630 ms gap without
    # stalling (docs/results/stall_runs.md): a load effect to bound, not this test's stall.
    # The feedback was really on: every node heard its peer's probes, and the GCS sized its copies
    # from them (64 until the first report, and at a stalled peer's "100 %"; 16 at no loss).
    assert all(r.peers_seen >= 1 for r in results), results
    assert all(r.repeats < 64 for r in results), [r.repeats for r in results]
