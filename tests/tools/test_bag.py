"""`zenoh-robot bag record|info|play` against live publishers: MCAP written, read back, cut short, replayed.

Real parts: a talker Node publishing over loopback sockets, the CLI as its own process
(session config pointing at the talker; no scouting), the mcap library reading the file.
"""
from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import pytest
from bag_helpers import cfg_session
from cli_helpers import CLI, ROOT
from conftest import wait_for
from mcap.reader import make_reader  # noqa: E402

from zenoh_robot import Node, msgs, qos  # noqa: E402
from zenoh_robot.tools.bag.encodings import PROTOBUF, RAW_ENVELOPE_SCHEMA  # noqa: E402
from zenoh_robot.tools.bag.info import Record, iter_records, read_info  # noqa: E402
from zenoh_robot.tools.bag.play import BagPlayer  # noqa: E402
from zenoh_robot.tools.bag.record import BagRecorder  # noqa: E402
from zenoh_robot.wire import ENVELOPE  # noqa: E402


def test_record_cli_writes_mcap_that_reads_back(bag_talker, ns, tmp_path):
    _node, _t, cfg = bag_talker
    out = tmp_path / "flight.mcap"
    r = subprocess.run([*CLI, "bag", "record", "--zenoh", str(cfg), "-a", "--duration", "3", "-o", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "a finished recording has a summary (index)"
        topics = {c.topic: c for c in summary.channels.values()}
        for t in (f"/{ns}/setpoint", f"/{ns}/state"):
            assert topics[t].message_encoding == "json"
            schema = summary.schemas[topics[t].schema_id]
            assert schema.encoding == "jsonschema"
            props = json.loads(schema.data)["properties"]
            assert "header" in props
        assert set(json.loads(summary.schemas[topics[f"/{ns}/state"].schema_id].data)["properties"]) >= {
            "position", "attitude", "mode", "armed"}
        # Foxglove decodes the raw channels too: a protobuf message with its FileDescriptorSet schema
        assert topics[f"/_zr/raw/{ns}/setpoint"].message_encoding == PROTOBUF
        raw_schema = summary.schemas[topics[f"/_zr/raw/{ns}/setpoint"].schema_id]
        assert (raw_schema.name, raw_schema.encoding) == (RAW_ENVELOPE_SCHEMA, "protobuf")
        assert topics[f"/_zr/raw/{ns}/setpoint"].metadata["zr.qos"], "the publisher's QoS is kept for replay"
        assert summary.schemas[topics[f"/{ns}/state/pose"].schema_id].name == "foxglove.PoseInFrame"
        assert summary.schemas[topics[f"/{ns}/state/fix"].schema_id].name == "foxglove.LocationFix"
        assert summary.schemas[topics[f"/{ns}/setpoint/pose"].schema_id].name == "foxglove.PoseInFrame"
        counts = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
        # ~50 Hz for 3 s minus discovery: far more than a handful, at most what was sent
        assert counts[f"/{ns}/setpoint"] > 40
        assert counts[f"/{ns}/setpoint"] == counts[f"/{ns}/setpoint/pose"]
        # the recorder's subscription drops repeated copies that bring nothing new: each raw envelope
        # (kept for replay, redundancy data and all) brought at least one sample, each sample is once in JSON
        assert 0 < counts[f"/_zr/raw/{ns}/setpoint"] <= counts[f"/{ns}/setpoint"]
        xs = []
        for _schema, _channel, message in reader.iter_messages(topics=[f"/{ns}/setpoint"]):
            data = json.loads(message.data)
            # log_time = arrival, publish_time = source stamp: same clock, so arrival is not earlier
            assert message.log_time >= message.publish_time
            xs.append(data["x"])
        assert xs == sorted(xs) and len(set(xs)) == len(xs), "every sample once, in order"


def record_in_process(node: Node, path: Path, seconds: float, **kw) -> BagRecorder:
    rec = BagRecorder(node, path, None, **kw).start()
    node.spin_until(lambda: False, seconds)    # its subscriptions deliver on the node's executor
    rec.close()
    return rec


def test_a_file_cut_short_still_reads_to_its_last_chunk(bag_talker, tmp_path):
    _node, _t, cfg = bag_talker
    path = tmp_path / "full.mcap"
    with Node("rec", config=cfg_session(cfg)) as rnode:
        rec = record_in_process(rnode, path, 3.0, flush_period=0.2, compression="zstd")
    full = [r for r in iter_records(path) if isinstance(r, Record)]
    assert rec.counters.written > 40 and len(full) == (rec.counters.written + rec.counters.raw_written
                                                        + rec.counters.views_written)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 6 // 10])     # the recorder died mid-flight
    with open(cut, "rb") as f:
        with pytest.raises(Exception):
            make_reader(f).get_summary()             # no footer, no index: plain readers give up
    kept = [r for r in iter_records(cut) if isinstance(r, Record)]
    assert 0 < len(kept) < len(full)
    # what survives is a prefix of the flight: the same messages in the same order
    assert [(r.channel.topic, r.message.log_time) for r in kept] == \
        [(r.channel.topic, r.message.log_time) for r in full[: len(kept)]]
    info = read_info(cut)
    assert not info.complete and info.messages == len(kept)
    r = subprocess.run([*CLI, "bag", "info", str(cut)], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and "cut short" in r.stdout, r.stdout + r.stderr


def test_info_lists_topics_counts_and_rates(bag_talker, ns, tmp_path):
    _node, _t, cfg = bag_talker
    path = tmp_path / "f.mcap"
    with Node("rec", config=cfg_session(cfg)) as rnode:
        rec = record_in_process(rnode, path, 2.0)
    r = subprocess.run([*CLI, "bag", "info", "--json", str(path)], cwd=ROOT, capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)     # strict JSON (json.loads would accept NaN; the writer refuses it)
    by_topic = {t["topic"]: t for t in info["topics"]}
    sp = by_topic[f"/{ns}/setpoint"]
    assert sp["type"] == "zenoh_robot/Setpoint" and sp["count"] == rec.counters.per_topic[f"/{ns}/setpoint"]
    assert 10 < sp["rate_hz"] < 200      # published at ~50 Hz; a loose band, machines are noisy
    text = subprocess.run([*CLI, "bag", "info", str(path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=30).stdout
    assert f"/{ns}/state" in text and "zenoh_robot/VehicleState" in text and "Duration:" in text


def test_play_republishes_bit_exact_into_a_live_subscriber(bag_talker, ns, tmp_path):
    node, t, cfg = bag_talker
    path = tmp_path / "f.mcap"
    with Node("rec", config=cfg_session(cfg)) as rnode:
        record_in_process(rnode, path, 2.0)
    t.stop.set()
    t.thread.join()
    records = [r for r in iter_records(path) if isinstance(r, Record) and r.channel.topic == f"/{ns}/setpoint"]
    recorded = [json.loads(r.message.data) for r in records]
    wire_stamp = {d["header"]["seq"]: r.message.publish_time for d, r in zip(recorded, records, strict=True)}
    assert len(recorded) > 20
    # A typed subscription on the talker's side: the replayed samples must decode as Setpoints.
    got: list[tuple[msgs.Setpoint, int, int]] = []
    node.create_subscription(msgs.Setpoint, "setpoint", lambda m, info: got.append((m, info.seq, info.source_stamp_ns)),
                             qos.SETPOINT.replace(depth=1000))
    spinner = threading.Thread(target=node.spin_until, args=(lambda: len(got) >= len(recorded), 30.0), daemon=True)
    spinner.start()
    with Node("player", config=cfg_session(cfg)) as pnode:
        player = BagPlayer(pnode, path, [f"/{ns}/setpoint"], rate=4.0)
        t0 = time.monotonic()
        c = player.play()
        took = time.monotonic() - t0
        assert wait_for(lambda: len(got) >= len(recorded) * 0.8, 5.0), (len(got), len(recorded))
        player.close()
    raw = [r for r in iter_records(path) if isinstance(r, Record) and r.channel.topic == f"/_zr/raw/{ns}/setpoint"]
    # A protobuf runtime decodes the raw channel from the file's own FileDescriptorSet, as Foxglove does:
    # each message's one field is an envelope, whose sequence number is at least the record's (an envelope
    # that also recovered older samples is recorded with the first of them).
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(raw[0].schema.data).file:
        pool.Add(file)
    Envelope = message_factory.GetMessageClass(pool.FindMessageTypeByName(raw[0].schema.name))
    envelopes = [Envelope.FromString(r.message.data).envelope for r in raw]
    assert all(ENVELOPE.unpack(e).seq >= r.message.sequence for e, r in zip(envelopes, raw, strict=True))
    # every wire copy goes out again (repeats included); the subscription delivers each sample once
    assert c.published == len(raw) and c.per_topic == {f"/{ns}/setpoint": len(raw)}
    assert len({m.header.seq for m, _, _ in got}) == len(got)
    # bit-exact: the same fields, sequence numbers and source stamps as recorded
    by_seq = {r["header"]["seq"]: r for r in recorded}
    for m, _seq, stamp in got:
        r = by_seq[m.header.seq]
        assert (m.x, m.y, m.z) == (r["x"], r["y"], r["z"]) and m.header.stamp == r["header"]["stamp"]
        assert stamp == wire_stamp[m.header.seq], "the envelope's source stamp travels unchanged"
    # original spacing, 4x faster: 2 s of flight takes at least ~0.3 s (lower bound only: no speed assert)
    span = (recorded[-1]["header"]["stamp"] - recorded[0]["header"]["stamp"]) / 1e9
    assert took >= span / 4 * 0.8
