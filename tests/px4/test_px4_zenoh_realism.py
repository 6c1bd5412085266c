"""The Zenoh simulator against PX4 SITL's own recordings (../shared/px4_zenoh_traces), row by row:
tokens, keys, hashes, payload and trailing lengths, attachments, rates, stray ACKs, the flight's
command/ACK sequence, the offboard-loss timings and the input variants V1-V7. Bands, not equality,
where PX4's numbers are times; the sim runs against a zenoh-python router as PX4 did."""
from __future__ import annotations

import json
import re
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from px4_zenoh_probe import Probe, probed_sim

from px4_zenoh.sim import ZenohSimulator

# CI lays out <root>/main (this repo) beside <root>/shared; a missing trace set fails, never skips.
TRACES = Path(__file__).resolve().parents[3] / "shared" / "px4_zenoh_traces"
DO_SET_MODE, ARM = 176, 400
ZID = re.compile(r"^(@ros2_lv/\d+/)[0-9a-f]+/")


def _json(rel: str) -> Any:
    path = TRACES / rel
    assert path.is_file(), f"PX4 Zenoh traces missing: {path} (the repo's parent must hold shared/)"
    return json.loads(path.read_text())


def _anon(token: str) -> str:
    return ZID.sub(r"\1<zid>/", token)


@pytest.fixture(scope="module")
def ground() -> Iterator[tuple[Probe, ZenohSimulator]]:
    with probed_sim(ready=False, seed=5) as (probe, sim):
        time.sleep(5.0)
        yield probe, sim


def test_tokens_are_px4s_modulo_zid_and_left_out_types(ground: tuple[Probe, ZenohSimulator]) -> None:
    probe, sim = ground
    theirs = {ln.strip() for ln in (TRACES / "tokens.txt").read_text().splitlines() if ln.startswith("@ros2_lv")}
    assert len(theirs) == 47
    left_out = {t.name.replace("/", "%") for t in sim.left_out}
    expected = {_anon(t) for t in theirs if t.split("/")[9:10] == [] or t.split("/")[9] not in left_out}
    ours = {_anon(t) for t in probe.tokens}
    assert ours == expected
    assert sim.left_out == () and len(ours) == 47 and all(t.endswith("::,7:,:,:,,") for t in ours if "/11/" in t)
    # the zid chunk is our session's ZenohId byte-reversed, as PX4's is
    zids = {t.split("/")[2] for t in probe.tokens}
    assert zids == {sim.zid} and sim.zid != str(probe.session.info.zid())


def test_every_published_topic_matches_the_ground_trace(ground: tuple[Probe, ZenohSimulator]) -> None:
    probe, sim = ground
    rows = _json("ground/ground_topics.json")
    gid = bytes.fromhex("aabbcc00000000000000000000000000")
    checked = 0
    for key, row in rows.items():
        topic = row["topic"].rsplit("/", 1)[1]
        if f"/fmu/out/{topic}" not in sim.rates and topic != "vehicle_command_ack":
            continue
        recs = probe.records(topic)
        assert recs, f"{topic}: nothing published"
        assert {r.key for r in recs} == {key}, f"{topic}: key (type or hash) differs from PX4's"
        assert {len(r.payload) for r in recs} == set(row["payload_len"]), topic
        assert {len(r.payload) - 4 - row["cdr_body_len"] for r in recs} == {row["trailing_len"]}, topic
        seqs, stamps = [], []
        for r in recs:
            assert r.attachment is not None and len(r.attachment) == 33, topic
            seq, t_us, n, g = struct.unpack("<qqB16s", r.attachment)
            assert (n, g) == (16, gid) and t_us % 4000 == 0, topic
            assert t_us == r.decode().timestamp if topic in ("vehicle_status", "vehicle_local_position") else True
            seqs.append(seq)
            stamps.append(t_us)
        assert seqs == list(range(1, len(seqs) + 1)), f"{topic}: seq from 1 with no gap"
        checked += 1
        if topic == "vehicle_command_ack":   # events, no rate
            continue
        span = (stamps[-1] - stamps[0]) / 1e6      # PX4's publish stamps: a loaded receiver does not move them
        rate = (len(recs) - 1) / span if span > 0 else 0.0
        if row["rate_hz"] >= 50:
            assert abs(rate - row["rate_hz"]) <= 0.1 * row["rate_hz"], f"{topic}: {rate:.1f} Hz vs {row['rate_hz']}"
        else:   # periodic plus on-change: a few seconds hold only a handful
            assert 0.5 * row["rate_hz"] <= rate <= 2 * row["rate_hz"] + 1.5, f"{topic}: {rate:.2f} Hz"
    assert checked == 11


def test_stray_gripper_acks_after_boot(ground: tuple[Probe, ZenohSimulator]) -> None:
    probe, _ = ground
    acks = [r.decode() for r in probe.records("vehicle_command_ack")]
    assert [(a.command, a.result, a.result_param1) for a in acks[:2]] == [(211, 5, 255), (211, 0, 0)]
    assert abs(acks[0].timestamp - 132000) <= 100000 and abs(acks[1].timestamp - 1228000) <= 100000
    assert (acks[0].target_system, acks[0].target_component) == (acks[1].target_system, acks[1].target_component)
    assert not acks[0].from_external


@pytest.fixture
def px4() -> Iterator[tuple[Probe, ZenohSimulator]]:
    with probed_sim(estimator_warmup_s=1.0, seed=7) as pair:
        yield pair


def _px4_time(sim: ZenohSimulator, msg: Any) -> float:
    """When PX4 stamped ``msg`` (its ``timestamp``, us since boot), on time.monotonic()'s clock."""
    return sim.boot_time + msg.timestamp / 1e6


def _answered_at(sim: ZenohSimulator, command: int, since: float) -> float:
    """When the simulator took ``command`` in (its own command log), the first time at or after ``since``."""
    return next(t for t, c, _ in sim.command_log if c == command and t >= since)


def _first_arrival(sim: ZenohSimulator, since: float, timeout: float) -> float:
    deadline = time.monotonic() + timeout
    while True:
        arrived = [t for t, _ in sim.setpoint_arrivals if t >= since]
        if arrived:
            return arrived[0]
        assert time.monotonic() < deadline, "no trajectory_setpoint reached the simulator"
        time.sleep(0.01)


def _offboard_and_arm(probe: Probe, sim: ZenohSimulator, z: float) -> None:
    """Each latency on PX4's clock (its message stamps and the simulator's records), as the trace has them:
    a loaded machine delays the probe's thread, not what PX4 did."""
    t0 = time.monotonic()
    probe.start_stream((0.0, 0.0, z))
    flag = probe.wait("failsafe_flags", lambda m: not m.offboard_control_signal_lost, 5.0, t0)
    assert flag is not None
    # PX4 clears the flag on offboard_control_mode; the probe puts the trajectory right after it, and a
    # loaded machine may run the flag's whole round trip in between: wait for the arrival, never race it.
    first = _first_arrival(sim, t0, 5.0)
    assert _px4_time(sim, flag[1]) - first < 0.25              # trace: 6 ms after the first setpoint
    time.sleep(1.5)                                            # trace: DO_SET_MODE 1.49 s after stream start
    t = probe.command(DO_SET_MODE, 1, 6)
    ack = probe.ack(DO_SET_MODE, t, timeout=5.0)
    assert ack is not None and ack[1].result == 0
    assert _px4_time(sim, ack[1]) - _answered_at(sim, DO_SET_MODE, t) < 0.25    # trace: 12 ms
    assert len([a for a in probe.records("vehicle_command_ack", t) if a.decode().command == DO_SET_MODE]) == 1
    status = probe.wait("vehicle_status", lambda m: m.nav_state == 14, 5.0, t)
    assert status is not None and _px4_time(sim, status[1]) - _px4_time(sim, ack[1]) < 0.25   # trace: 24 ms
    t = probe.command(ARM, 1)
    ack = probe.ack(ARM, t, timeout=5.0)
    assert ack is not None and ack[1].result == 0
    assert _px4_time(sim, ack[1]) - _answered_at(sim, ARM, t) < 0.25    # trace: 3 ms
    assert probe.wait("vehicle_status", lambda m: m.arming_state == 2, 5.0, t) is not None


def test_flight_commands_and_acks_as_in_the_trace(px4: tuple[Probe, ZenohSimulator]) -> None:
    probe, sim = px4
    summary = _json("flight/flight_summary.json")
    _offboard_and_arm(probe, sim, -1.0)
    for step in ("offboard", "arm"):
        want = summary[step]["ack"]
        got = probe.latest("vehicle_command_ack")
        if step == "offboard":
            got = [r.decode() for r in probe.records("vehicle_command_ack") if r.decode().command == DO_SET_MODE][-1]
        fields = ("command", "result", "result_param1", "result_param2", "target_system", "target_component",
                  "from_external")
        assert {f: getattr(got, f) for f in fields} == {f: want[f] for f in fields}, step


def test_offboard_loss_timings_as_in_the_trace(px4: tuple[Probe, ZenohSimulator]) -> None:
    probe, sim = px4
    loss = _json("loss/loss_summary.json")["loss"]
    _offboard_and_arm(probe, sim, -1.0)
    assert probe.wait("vehicle_local_position", lambda m: m.z < -0.8, 15.0) is not None
    stopped = probe.stop_stream()
    flag = probe.wait("failsafe_flags", lambda m: m.offboard_control_signal_lost, 5.0, stopped)
    rtl = probe.wait("vehicle_status", lambda m: m.nav_state == 5, 5.0, stopped)
    assert flag is not None and rtl is not None
    # After the last setpoint PX4 received, on its clock (its stamps and the simulator's arrival record).
    last = sim.setpoint_arrivals[-1][0]
    assert abs((_px4_time(sim, flag[1]) - last) - loss["offboard_signal_lost_flag_after_s"]) < 0.15
    want = loss["status_changes_after_stop"][0]
    assert abs((_px4_time(sim, rtl[1]) - last) - want["after_s"]) < 0.15
    assert (rtl[1].failsafe, rtl[1].arming_state, rtl[1].nav_state_user_intention) == (True, 2, want["user_intention"])
    assert [e.action for e in sim.failsafe_log] == ["AUTO.RTL"]


def test_input_variants_v1_to_v7(px4: tuple[Probe, ZenohSimulator]) -> None:
    probe, _ = px4
    want = {v["label"].split()[0]: ([a["result"] for a in v["acks"]], v["nav_state_after_1.5s"])
            for v in _json("variants/variants_summary.json")["variants"]}

    def run(label: str, command: int, *params: float, **kw: Any) -> None:
        t = probe.command(command, *params, **kw)
        ack = probe.ack(command, t, timeout=0.7)
        results = [] if ack is None else [ack[1].result]
        if ack is not None:
            assert (ack[1].target_system, ack[1].target_component) == (1, 1), label
        time.sleep(0.3)
        status = probe.latest("vehicle_status")
        assert (results, status.nav_state) == want[label], label

    probe.start_stream((0.0, 0.0, 0.0), attachment=False)
    assert probe.wait("failsafe_flags", lambda m: not m.offboard_control_signal_lost, 2.0) is not None
    run("V1", DO_SET_MODE, 1, 6, attachment=False)
    run("V2", DO_SET_MODE, 1, 4, 3, target_system=2)
    run("V3", DO_SET_MODE, 1, 4, 3, target_system=0, target_component=0)
    run("V4", DO_SET_MODE, 1, 6, extra=bytes(24))
    probe.stop_stream()
    time.sleep(2.0)
    run("V5a", DO_SET_MODE, 1, 4, 3)
    run("V5b", DO_SET_MODE, 1, 6)
    run("V7", ARM, 1)
    probe.start_stream((0.0, 0.0, 0.0))
    time.sleep(0.3)
    run("V6", DO_SET_MODE, 1, 6)
