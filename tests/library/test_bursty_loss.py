"""Bursty loss (issue #29): the loss feedback's burst estimate, the copies it sizes, and the netns
harness's two-state (Gilbert-Elliott) channel measured on real datagrams between two namespaces.

The netns test needs root; with ZR_REQUIRE_NETNS=1 (CI) a missing capability fails it."""
from __future__ import annotations

import json
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import bare_loss_monitor, skip_unless_required

from drone_lab.experiment.netns import BurstModel, LossyLink, unavailable_reason
from zenoh_robot.loss_feedback import BurstEstimate, LinkProbe, LossMonitor, repeat_plan

PERIOD = 0.05


def _estimator(monkeypatch: pytest.MonkeyPatch) -> tuple[LossMonitor, list[float]]:
    """A LossMonitor's estimator alone, on a clock the test drives (no session, no probe thread)."""
    monitor: LossMonitor
    monitor, clock = bare_loss_monitor(monkeypatch)
    return monitor, clock


def _feed(m: LossMonitor, clock: list[float], lost: list[bool], seq0: int = 0) -> None:
    for i, drop in enumerate(lost):
        clock[0] = 1000.0 + (seq0 + i) * PERIOD
        if not drop:
            m._on_probe(LinkProbe(2, (seq0 + i) & 0xFFFFFFFF, round(PERIOD * 1000), [], []))


def _gilbert(n: int, rnd: random.Random, bad_s: float = 0.3, bad: float = 0.95, good: float = 0.05) -> list[bool]:
    """Per-probe drops of a two-state channel at a 50 % mean (equal mean good and bad periods)."""
    out: list[bool] = []
    state_bad = False
    left = 0.0
    for _ in range(n):
        while left <= 0:
            state_bad = not state_bad
            left += min(2.0, max(0.1, rnd.expovariate(1 / bad_s)))
        out.append(rnd.random() < (bad if state_bad else good))
        left -= PERIOD
    return out


def test_burst_estimate_tells_fades_from_independent_loss_at_the_same_mean(monkeypatch) -> None:
    """40 windows of 5 s (the long window) each way, at a 50 % mean: the median estimate."""
    rnd = random.Random(29)
    uniform, fades, means = [], [], []
    for _ in range(40):
        m, clock = _estimator(monkeypatch)
        _feed(m, clock, [rnd.random() < 0.5 for _ in range(100)])
        uniform.append(m.burst())
        m, clock = _estimator(monkeypatch)
        drops = _gilbert(100, rnd)
        means.append(sum(drops) / len(drops))
        _feed(m, clock, drops)
        fades.append(m.burst())

    def median(values: list[float]) -> float:
        return sorted(values)[len(values) // 2]
    assert 0.45 <= median(means) <= 0.55                                   # the same mean ...
    assert 0.4 <= median([b.loss_after_loss for b in uniform]) <= 0.6      # independent: as the mean
    assert 1.6 <= median([b.mean_run for b in uniform]) <= 2.5
    assert median([b.loss_after_loss for b in fades]) >= 0.7               # ... but a loss follows a loss
    assert median([b.mean_run_s for b in fades]) >= 0.15                   # runs of fade length
    assert median([b.longest_run_s for b in fades]) >= 0.4


def test_burst_estimate_forgets_old_runs_and_ignores_late_probes_and_restarts(monkeypatch) -> None:
    m, clock = _estimator(monkeypatch)
    _feed(m, clock, [False] * 10 + [True] * 8 + [False] * 10)      # one run of 8
    b = m.burst()
    assert (b.longest_run, b.mean_run, b.loss_after_loss) == (8, 8.0, 1 - 1 / 8)
    assert abs(b.longest_run_s - 0.4) < 1e-9
    m._on_probe(LinkProbe(2, 5, 50, [], []))                        # a late (or replayed) probe
    m._on_probe(LinkProbe(2, 27, 50, [], []))                       # a duplicate
    assert m.burst() == b
    _feed(m, clock, [False] * 120, seq0=28)                         # 6 s clean: the run left the window
    assert m.burst().longest_run == 0 and m.burst().loss_after_loss == 0.0
    clock[0] += PERIOD
    m._on_probe(LinkProbe(2, 10_000_000, 50, [], []))               # the peer restarted its count
    assert m.burst().longest_run == 0
    _feed(m, clock, [True] * 3 + [False], seq0=10_000_001)          # wraps nowhere, counts on
    assert m.burst().longest_run == 3
    m2, clock2 = _estimator(monkeypatch)                            # the 32-bit seq wraps
    _feed(m2, clock2, [False, False, True, True, False], seq0=0xFFFFFFFE)
    assert m2.burst().longest_run == 2


def test_each_drone_is_sized_for_its_own_link(monkeypatch) -> None:
    """A GCS hears two drones: uav1 clean, uav2 in a fade. Per origin, uav1's copies stay those of
    a clean link and uav2's follow its fade (before, the worst of all sized every drone's). A drone
    not heard yet is sized like the worst link; a third peer claiming uav2's name with a clean link
    cannot lower uav2's figure, and an over-long origin is refused."""
    m, clock = _estimator(monkeypatch)
    for i in range(100):                               # 5 s: uav1 every probe; uav2 silent from 3 s
        clock[0] = 1000.0 + i * PERIOD
        m._on_probe(LinkProbe(2, i, 50, [], [], "uav1"))
        if i < 60:
            m._on_probe(LinkProbe(3, i, 50, [], [], "uav2"))
    assert m.outgoing_loss("uav1") < 0.05
    assert m.outgoing_loss("uav2") > 0.3
    assert not m.burst("uav1").fading and m.burst("uav2").fading
    assert m.outgoing_loss("uav9") == m.outgoing_loss() == m.outgoing_loss("uav2")

    def copies_per_s(origin: str) -> float:
        copies, window = repeat_plan(m.outgoing_loss(origin), 1.0, burst=m.burst(origin), period_s=0.1)
        return copies / window
    assert copies_per_s("uav1") < copies_per_s("uav2")
    for i in range(100, 120):                          # an impostor, clean, under uav2's name
        clock[0] = 1000.0 + i * PERIOD
        m._on_probe(LinkProbe(4, i, 50, [], [], "uav2"))
    assert m.outgoing_loss("uav2") > 0.3 and m.burst("uav2").fading
    bad = m.bad_probes
    m._on_probe(LinkProbe(5, 1, 50, [], [], "x" * 129))
    assert m.bad_probes == bad + 1 and all(p.origin != "x" * 129 for p in m._peers.values())


def test_copies_sized_for_fades_cross_a_95_percent_fade_within_the_deadline() -> None:
    deadline = 0.5
    for mean, cond in ((0.5, 0.5), (0.3, 0.3)):                    # independent loss: unchanged
        independent = BurstEstimate(loss_after_loss=cond, lost=50, received=50)
        assert repeat_plan(mean, deadline, burst=independent) == repeat_plan(mean, deadline)
    flat = repeat_plan(0.5, deadline)
    # What 95 % fades at a 50 % mean read as on 100 probes (5 s): a loss follows a loss far more often.
    bursty = repeat_plan(0.5, deadline, burst=BurstEstimate(loss_after_loss=0.78, lost=50, received=50))
    rate_flat, rate_bursty = flat[0] / flat[1], bursty[0] / bursty[1]
    # Inside a 95 % fade, the chance that no copy crosses in a 500 ms deadline:
    assert 0.95 ** (deadline * rate_flat) > 0.1                     # the mean-sized plan: often
    assert 0.95 ** (deadline * rate_bursty) < 0.01, bursty          # sized for the fade: rarely
    assert bursty[0] <= 64


def test_burst_model_keeps_the_mean() -> None:
    m = BurstModel()
    good, bad, good_mean = m.states(50)
    share = m.bad_mean() / (m.bad_mean() + good_mean)
    assert (good, bad) == (5.0, 95.0) and abs(share * bad + (1 - share) * good - 50) < 1e-9
    assert 0.3 <= m.bad_mean() <= 0.33                              # 300 ms, clamped to 0.1..2 s
    assert m.states(4)[:2] == (2.0, 95.0) and m.states(4)[2] > 10     # rare fades at a low mean
    assert m.states(0)[2] == float("inf") and m.states(99)[2] == 0.0


# -- the channel on real datagrams -----------------------------------------------------------------

RECV = """
import json, os, socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
s.bind((sys.argv[1], 9999)); s.settimeout(0.5)
print("READY", flush=True)
# Until the sender is done (the stop file), not for a fixed time: a sender slow to start on a loaded
# machine would otherwise lose its tail, counted as drops.
got, end = [], time.monotonic() + float(sys.argv[2])
while time.monotonic() < end and not os.path.exists(sys.argv[3]):
    try:
        got.append(int(s.recv(64)))
    except socket.timeout:
        pass
print(json.dumps(got))
"""
SEND = """
import socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
n, gap = int(sys.argv[2]), float(sys.argv[3])
t = time.monotonic()
for i in range(n):
    s.sendto(str(i).encode(), (sys.argv[1], 9999))
    t += gap
    time.sleep(max(0.0, t - time.monotonic()))
"""
RATE = 400      # datagrams per second: a 100 ms fade is 40 of them


def _drops(link: LossyLink, seconds: float, stop: Path) -> tuple[list[bool], int, int]:
    """Send RATE datagrams/s GCS -> drone for ``seconds``; which were lost, and the window (ns)."""
    n = int(seconds * RATE)
    recv = subprocess.Popen(link.exec_in("drone") + [sys.executable, "-c", RECV, link.addr("drone"),
                            str(seconds + 60), str(stop)], stdout=subprocess.PIPE, text=True)
    assert recv.stdout is not None and recv.stdout.readline().strip() == "READY"
    t0 = time.time_ns()
    subprocess.run(link.exec_in("gcs") + [sys.executable, "-c", SEND, link.addr("drone"), str(n), str(1 / RATE)],
                   check=True, timeout=seconds + 30)
    t1 = time.time_ns()
    time.sleep(0.5)         # the last datagrams cross the veth
    stop.touch()
    out, _ = recv.communicate(timeout=30)
    got = set(json.loads(out.strip().splitlines()[-1]))
    return [i not in got for i in range(n)], t0, t1


def _runs(drops: list[bool]) -> list[int]:
    runs, n = [], 0
    for d in drops:
        if d:
            n += 1
        elif n:
            runs.append(n)
            n = 0
    return runs + ([n] if n else [])


@pytest.mark.netns
def test_bursty_channel_keeps_the_mean_and_drops_in_bursts(tmp_path: Path) -> None:
    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"bursty-loss test: network namespaces are unavailable: {reason}")
    with LossyLink(loss_pct=0, loss_model="bursty", burst=BurstModel(seed=29)) as link:
        link.set_loss(50)
        time.sleep(0.3)
        drops, t0, t1 = _drops(link, 15.0, tmp_path / "stop")
        summary = link.timeline_summary(t0, t1)
        link.set_loss(0)
        assert link.timeline[-1][1:] == ("clean", 0)
    realised = 100 * sum(drops) / len(drops)
    applied = summary["mean_pct"]
    # The packets lost are the loss the channel applied (what was recorded is what happened) ...
    assert applied is not None and abs(realised - applied) < 6, (realised, summary)
    # ... and over 15 s (~25 fades) that is the mean asked for.
    assert 35 <= realised <= 65, (realised, summary)
    runs = _runs(drops)
    # Fades: drops come in runs far longer than independent 50 % loss gives (longest ~12 of 6000).
    # A fade drops ~95 % for 100 ms-2 s: a run of 40 (100 ms) is 3x what 50 % uniform loss gives (~12).
    assert max(runs) >= 0.1 * RATE, (max(runs), summary)
    assert sum(runs) / len(runs) >= 3, (sum(runs) / len(runs), summary)
    assert summary["bad_periods"] >= 8 and 0.15 <= summary["bad_mean_s"] <= 0.6, summary
