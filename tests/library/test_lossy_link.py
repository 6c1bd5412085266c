"""A short lossy cell between two network namespaces (veth + nftables random drop).

Needs root. With ZR_REQUIRE_NETNS=1 (CI) a missing capability fails the test instead of
skipping it, so CI can never pass by silently skipping the one thing it must prove.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import last_json, skip_unless_required, wait_ready

from drone_lab.experiment.netns import LossyLink, unavailable_reason

ROOT = Path(__file__).resolve().parents[2]
PEER = str(ROOT / "tests" / "procs" / "lossy_peer.py")


@pytest.fixture
def lossy_link():
    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"lossy-link test: network namespaces are unavailable: {reason}")
    link = LossyLink(loss_pct=0)
    with link:
        yield link
    assert not link.exists(), "namespaces left behind"


def _cell(link: LossyLink, profile: str, loss: float, tmp_path: Path, duration: float = 5.0,
          rate: float = 20.0) -> tuple[int, dict]:
    start, stop = tmp_path / f"start-{profile}", tmp_path / f"stop-{profile}"
    common = ["--ns", f"cell{profile}", "--profile", profile, "--rate", str(rate)]
    sub = subprocess.Popen(link.exec_in("drone") + [sys.executable, PEER, "sub", *common,
                           "--listen", f"tcp/{link.addr('drone')}:7447", "--listen", f"udp/{link.addr('drone')}:7447",
                           "--duration", str(duration + 60), "--stop-file", str(stop)],
                           stdout=subprocess.PIPE, text=True, cwd=ROOT)
    pub = subprocess.Popen(link.exec_in("gcs") + [sys.executable, PEER, "pub", *common,
                           "--connect", f"tcp/{link.addr('drone')}:7447", "--connect", f"udp/{link.addr('drone')}:7447",
                           "--duration", str(duration), "--start-file", str(start)],
                           stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert wait_ready(sub)
    assert wait_ready(pub)
    time.sleep(1.5)                 # sessions up (the thesis applied loss after set-up)
    link.set_loss(loss)
    start.touch()
    pub_out, _ = pub.communicate(timeout=duration + 20)
    stop.touch()                    # the publisher lingered 1 s after its last sample: copies have landed
    sub_out, _ = sub.communicate(timeout=20)
    assert pub.returncode == 0 and sub.returncode == 0, (pub_out, sub_out)
    sent = last_json(pub_out)["sent"]
    return sent, last_json(sub_out)


@pytest.mark.netns
def test_setpoints_at_10_percent_loss(lossy_link: LossyLink, tmp_path: Path) -> None:
    sent, be = _cell(lossy_link, "setpoint", 10, tmp_path)
    received = set(be["seqs"])
    # Best effort loses some, but keeps arriving. (The gap bound is loose: a shared 2-core machine
    # can stall a process for a moment; the experiment measures gaps against PX4's 500 ms.)
    assert 0.7 * sent <= len(received) <= sent
    assert be["max_gap"] is not None and be["max_gap"] < 1.0

    sent, res = _cell(lossy_link, "resilient", 10, tmp_path)
    assert sorted(set(res["seqs"])) == list(range(sent)), f"resilient lost {sent - len(set(res['seqs']))}"
    assert res["seqs"] == sorted(res["seqs"]), "delivered out of order"
    assert res["max_gap"] < 1.0


@pytest.mark.fast
def test_reliable_profile_never_drops_at_the_sender() -> None:
    """The thesis's `reliable` profile (RELIABLE, keep last 10) lost 12 % of sensor samples at 10 %
    loss: KEEP_LAST mapped to CongestionControl.DROP, and Zenoh drops a sample that finds its
    2-batch queue full for 1 ms (TCP retransmitting). Reliable blocks instead; best effort drops."""
    import zenoh

    from drone_contract.streams import PROFILES
    from zenoh_robot.qos_mapping import publisher_options

    for stream, q in PROFILES["reliable"].qos.items():
        assert publisher_options(q)["congestion_control"] == zenoh.CongestionControl.BLOCK, stream
    for stream, q in PROFILES["best_effort"].qos.items():
        assert publisher_options(q)["congestion_control"] == zenoh.CongestionControl.DROP, stream


@pytest.mark.netns
def test_fec_images_arrive_whole_at_30_percent_loss(lossy_link: LossyLink, tmp_path: Path) -> None:
    """Sliced JPEG strips gave ~1 % whole fresh frames at 30 % loss (a frame needs all ~8 packets);
    one JPEG in shares + parity sized for 30 % is whole whenever >= k of n shares arrive."""
    peer = str(ROOT / "tests" / "procs" / "fec_peer.py")
    start, stop = tmp_path / "start", tmp_path / "stop"
    duration = 4.0
    common = ["--ns", "cellfec", "--loss", "0.3"]
    sub = subprocess.Popen(lossy_link.exec_in("drone") + [sys.executable, peer, "sub", *common, "--iface",
                           lossy_link.dev("drone"), "--duration", str(duration + 60), "--stop-file", str(stop)],
                           stdout=subprocess.PIPE, text=True, cwd=ROOT)
    pub = subprocess.Popen(lossy_link.exec_in("gcs") + [sys.executable, peer, "pub", *common, "--iface",
                           lossy_link.dev("gcs"), "--duration", str(duration), "--start-file", str(start)],
                           stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert wait_ready(sub)
    assert wait_ready(pub)
    time.sleep(1.5)
    lossy_link.set_loss(30)
    start.touch()
    pub_out, _ = pub.communicate(timeout=duration + 20)
    stop.touch()
    sub_out, _ = sub.communicate(timeout=20)
    assert pub.returncode == 0 and sub.returncode == 0, (pub_out, sub_out)
    sent = last_json(pub_out)
    got = last_json(sub_out)
    whole = len(set(got["frames"]))
    assert sent["n"] > sent["k"] and got["decode_errors"] == 0
    # Generous (the old figure was ~1 %), yet fails if parity did not work: 30 % loss on ~8 shares
    # without parity leaves ~6 % of frames whole.
    assert whole >= 0.6 * sent["sent"], (whole, sent)
    assert 0.15 < got["share_loss"] < 0.5, got["share_loss"]


@pytest.mark.netns
def test_experiment_cell_window_lies_within_both_apps_streams(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A cell's window must be timed from the apps (docs/zenoh-multicast-stall.md, 2026-11-23).

    Timed from the launch, a window opened before the apps streamed when start-up outlasted the
    warm-up (6-11 s seen under load) and ran past their exit when the parent's own steps were slow;
    the analysis read those seconds as every stream silent at once. Here both apps start slowly on
    purpose (a sitecustomize that sleeps 3 s, as imports on a loaded machine do): with the old timing
    the window opened before any stream, every run; now it must lie within both apps' streams."""
    from drone_lab.experiment.cell import CellSpec, run_cell

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"experiment cell test: network namespaces are unavailable: {reason}")
    slow = tmp_path / "slow_start"
    slow.mkdir()
    (slow / "sitecustomize.py").write_text("import time\ntime.sleep(3.0)\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(slow), os.environ.get("PYTHONPATH")])))
    r = run_cell(CellSpec("resilient", 0, duration=2.0, warmup=2.5), tmp_path / "cell")
    assert not r.get("error"), r.get("error")
    assert r["exit_codes"] == {"drone": 0, "gcs": 0}, r["exit_codes"]
    assert r["startup_s"] is not None
    assert "invalid" not in r, r["invalid"]
    t0, t1 = r["window_ns"]
    gcs = json.loads((tmp_path / "cell" / "gcs.json").read_text())["drones"]["uav1"]["logs"]
    drone = json.loads((tmp_path / "cell" / "drone.json").read_text())["logs"]
    records = {"setpoints sent": gcs["sent"]["setpoint"], "setpoints received": drone["received"]["setpoint"],
               "sensor sent": drone["sent"]["sensor"], "sensor received": gcs["received"]["sensor"]}
    for name, rec in records.items():
        assert min(rec["arrival_ns"]) < t0 and max(rec["arrival_ns"]) > t1, f"{name} do not cover the window"
    # Nothing in the window is a start-up or shut-down artefact: at 0 % loss every setpoint sent in it arrived.
    assert r["topics"]["setpoint"]["delivered_pct"] == 100.0
    # The FEC frames the GCS rebuilt count as fresh strips too (both ends number them frame * MAX_SLICES).
    whole, strip = r["topics"]["image_whole"], r["topics"]["image_strip"]
    assert whole["unique"] > 0 and strip["delivered_pct"] == whole["delivered_pct"], (whole, strip)


@pytest.mark.fast
def test_sweep_resume_reruns_invalid_cells_and_reports_skip_them(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A cell flagged ``invalid`` (its window missed the apps' streams) measured nothing about the link:
    the report must not show it and ``--resume`` must run it again. A session that never formed is
    a result (kept, not rerun); a harness error is rerun."""
    from drone_lab.experiment import sweep
    from drone_lab.experiment.cell import CellSpec

    def line(loss: float, **kw: object) -> str:
        return json.dumps({"profile": "resilient@router", "transport": "router", "loss": loss, "start": "startup",
                           "topics": {}, **kw})
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "results.jsonl").write_text("\n".join([
        line(0), line(10, invalid="setpoint not sent through the whole window"),
        line(30, error="no session within 60 s", no_session=True), line(50, error="RuntimeError: boom"),
        line(70), line(70, invalid="late"), '{"cut by a cras']) + "\n")
    shown = {r["loss"]: r for r in sweep.load_results(out / "results.jsonl")}
    assert sorted(shown) == [0, 30, 50, 70] and not shown[70].get("invalid")   # a later invalid never hides a valid
    ran: list[float] = []

    def fake_run_cell(spec: CellSpec, workdir: Path) -> dict:
        ran.append(spec.loss)
        return {"profile": spec.label, "transport": spec.transport, "loss": spec.loss, "start": spec.start,
                "topics": {}}
    monkeypatch.setattr(sweep, "run_cell", fake_run_cell)
    cells = [CellSpec("resilient", loss, "startup", 1.0, 1.0, "router") for loss in (0, 10, 30, 50, 70, 90)]
    results = sweep.run_sweep(out, cells, resume=True)
    assert sorted(ran) == [10, 50, 90]
    assert sorted(r["loss"] for r in results) == [0, 10, 30, 50, 70, 90]
    assert not any(r.get("invalid") for r in results)


@pytest.mark.netns
def test_router_cell_from_a_lossy_start(tmp_path: Path) -> None:
    """Issue #17 item 6: the resilient profile through a ground router, 30 % loss from start-up (the
    companion's handshake crosses it). Once the session has formed, every setpoint arrives with no
    gap over PX4's 500 ms, images arrive whole, and a command crosses the router both ways."""
    from drone_lab.experiment.cell import CellSpec, run_cell

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"router cell test: network namespaces are unavailable: {reason}")
    # The window opens `warmup` s after the companion's session opened; the GCS starts a drone's
    # setpoints once it has heard its state, which across 30 % loss on TCP took up to 3.3 s (a CI
    # run: its window opened 1.2 s before the first setpoint, read as a 1.2 s gap). 4 s as the sweep.
    # A client's TCP handshake with the router across 30 % loss backs off as TCP does (1, 2, 4, 8 s...): its
    # session opened 19.6 s after launch in a CI rehearsal with a neighbouring flight. What is asserted
    # starts once the session has formed; the time to form it is the sweep's figure (docs/lossy-link.md).
    r = run_cell(CellSpec("resilient", 30, "startup", duration=3.0, warmup=4.0, transport="router",
                          startup_timeout=45.0), tmp_path / "cell")
    assert not r.get("error"), r.get("error")
    assert "invalid" not in r, r["invalid"]
    assert r["exit_codes"] == {"router": 0, "drone": 0, "gcs": 0}, r["exit_codes"]
    assert r["session_formed_s"] is not None
    sp = r["topics"]["setpoint"]
    assert sp["delivered_pct"] >= 99.0 and sp["longest_gap_ms"] <= 500.0, sp
    assert r["topics"]["image_whole"]["delivered_pct"] >= 50.0, r["topics"]["image_whole"]
    # The drone reached the router across the veth (not some other path), with both links.
    router_log = (tmp_path / "cell" / "router.log").read_text()
    assert "router: 2 connected" in router_log, router_log
    assert r["command"]["answered"], r["command"]


def test_a_cell_window_ends_by_the_patterns_planned_end_never_its_recorded_one(tmp_path: Path) -> None:
    """Switching the loss on took seconds under load (rehearsal 16), and the window, timed from it, took the land
    in: it ends by the pattern's planned end. Planned, not recorded: a mission that failed early keeps its
    failure inside the window."""
    from drone_lab.experiment.cell import _pattern_end_ns

    assert _pattern_end_ns(tmp_path, 12.0) is None                           # no GCS record
    (tmp_path / "gcs.json").write_text(json.dumps({"mission": {"pattern_window": [1000.0, 1003.5]}}))
    assert _pattern_end_ns(tmp_path, 12.0) == 1012 * 10**9                  # failed at 3.5 s: still 12 s
    (tmp_path / "gcs.json").write_text(json.dumps({"mission": {"steps": []}}))
    assert _pattern_end_ns(tmp_path, 12.0) is None                           # never flew the pattern


@pytest.mark.netns
def test_a_cell_flies_its_mission_through_50_percent_loss(tmp_path: Path) -> None:
    """Issue #29: the cell flies. The GCS's mission arms the drone, enters OFFBOARD and flies the square
    through 50 % uniform loss (on once the drone is up in OFFBOARD) and lands; the cell records what the
    vehicle did: armed in OFFBOARD through the whole window with no failsafe, the target PX4 is given
    never older than PX4's 500 ms, the path error, and the commands through the real companion."""
    from drone_lab.experiment.cell import CellSpec, run_cell

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"flying cell test: network namespaces are unavailable: {reason}")
    r = run_cell(CellSpec("resilient", 50, duration=8.0, warmup=2.0), tmp_path / "cell")
    assert not r.get("error") and not r.get("invalid") and not r.get("mission_failed"), r
    fl = r["flight"]
    assert fl["mission_ok"], fl["mission_result"]
    assert fl["airborne"] and fl["armed_in_window"], fl
    assert fl["offboard_share_window"] == 1.0 and fl["failsafes"] == 0, fl
    assert r["offboard_kept"] and r.get("window_cut_s", 0.0) < 4.0, r.get("window_cut_s")
    assert 40.0 <= r["channel"]["mean_pct"] <= 60.0, r["channel"]    # the loss was on in the window
    target = fl["vehicle_target"]
    assert target["samples"] >= 200, target                           # ~8 s at 50 Hz
    assert 0 < target["age_max_ms"] < 500.0 and target["stale_over_500ms"] == 0, target
    err = fl["path_error_window"]
    assert err["samples"] >= 200 and 0 <= err["mean_m"] <= err["max_m"] < 3.0, err
    cmds = fl["commands"]
    for name in ("offboard_start", "arm", "land"):
        assert cmds[name]["ok"] and 0 <= cmds[name]["s"] < 10.0, (name, cmds)
    # The hold from a second GCS crossed the loss and the real companion answered it (a refusal: it holds
    # no control), while the mission flew on.
    assert cmds["hold"]["ok"] and "refused" in cmds["hold"]["detail"], cmds["hold"]
    assert r["topics"]["setpoint"]["sent"] >= 70, r["topics"]["setpoint"]
    assert r["bandwidth_kBps"]["gcs"] > 0 and r["bandwidth_kBps"]["drone"] > 0, r["bandwidth_kBps"]
    assert (tmp_path / "cell" / "vehicle.jsonl").stat().st_size > 0


class _Addresses:
    """What transport_for asks of a link: each side's address (no namespaces needed)."""

    def addr(self, side: str) -> str:
        return {"gcs": "10.77.0.1", "drone": "10.77.0.2"}[side]

    def dev(self, side: str) -> str:
        return f"veth-{side}"


@pytest.mark.fast
def test_thesis_variants_through_a_router_are_plain_clients_over_tcp() -> None:
    from drone_lab.experiment.cell import ROUTER_LOCAL, transport_for

    link: Any = _Addresses()
    for profile in ("reliable", "best_effort"):
        gcs, drone = (transport_for(profile, link, side, "router") for side in ("gcs", "drone"))
        assert (gcs["mode"], drone["mode"]) == ("client", "client")
        assert gcs["connect"]["endpoints"] == [ROUTER_LOCAL]
        assert drone["connect"]["endpoints"] == ["tcp/10.77.0.1:7447"]
        assert drone["listen"]["endpoints"] == [] and not drone["scouting"]["multicast"]["enabled"]
        # Zenoh's defaults, as the thesis ran them: none of the resilient profile's lossy tuning (the link
        # protocols' whitelist without UDP changes nothing for a client of one TCP link).
        assert "tx" not in drone["transport"].get("link", {}) and "tx" not in gcs["transport"].get("link", {})
        assert "tx" in transport_for("resilient", link, "drone", "router")["transport"]["link"]
        with pytest.raises(ValueError, match="resilient profile only"):
            transport_for(profile, link, "drone", "unicast")
