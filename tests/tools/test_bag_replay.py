"""bag: the recorder in the graph, replay per original publisher and in loops, --exclude/--domain, image slices.

Real parts: talker Nodes publishing over loopback sockets, the recorder and player on their
own sessions, the CLI as its own process, the mcap reader.
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
from bag_helpers import cfg_session
from cli_helpers import CLI, ROOT
from conftest import free_port, linked_configs, wait_for
from mcap.reader import make_reader  # noqa: E402

from drone_contract.messages import VehicleState  # noqa: E402
from zenoh_robot import Node, msgs, qos  # noqa: E402
from zenoh_robot.graph import EndpointType, decode_qos  # noqa: E402
from zenoh_robot.image.sliced import ImagePublisher  # noqa: E402
from zenoh_robot.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from zenoh_robot.tools.bag.info import Record, iter_records  # noqa: E402
from zenoh_robot.tools.bag.play import BagPlayer  # noqa: E402
from zenoh_robot.tools.bag.record import BagRecorder  # noqa: E402


class Spinning:
    """Spin a node on a thread until the block ends."""

    def __init__(self, node: Node) -> None:
        self.stop = threading.Event()
        self.thread = threading.Thread(target=node.spin_until, args=(self.stop.is_set, 60.0), daemon=True)

    def __enter__(self) -> "Spinning":
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()


def _summary_topics(path: Path) -> dict[str, list]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    out: dict[str, list] = {}
    for c in summary.channels.values():
        out.setdefault(c.topic, []).append(c)
    return out


def test_recorder_is_a_subscriber_in_topic_info(bag_talker, ns, tmp_path):
    _node, _t, cfg = bag_talker
    # Peers linked to the talker only do not see each other: the CLI links to the recorder too.
    base = cfg_session(cfg)
    rec_endpoint = f"tcp/127.0.0.1:{free_port()}"
    cli_cfg = tmp_path / "cli.json5"
    cli_cfg.write_text(json.dumps(dataclasses.replace(base, connect=[*base.connect, rec_endpoint]).to_json5()))
    with Node("flight_recorder", config=dataclasses.replace(base, listen=[rec_endpoint])) as rnode, Spinning(rnode):
        rec = BagRecorder(rnode, tmp_path / "f.mcap", None).start()
        try:
            assert wait_for(lambda: rec.counters.written > 10, 10.0)
            for _ in range(3):     # the CLI answers once it sees the topic: the recorder's link may come second
                r = subprocess.run([*CLI, "topic", "info", "-v", "--zenoh", str(cli_cfg), f"/{ns}/setpoint"],
                                   cwd=ROOT, capture_output=True, text=True, timeout=60)
                if "Subscription count: 1" in r.stdout:
                    break
        finally:
            rec.close()
    assert r.returncode == 0, r.stderr
    assert "Subscription count: 1" in r.stdout and "Node name: flight_recorder" in r.stdout, r.stdout
    # a raw subscription takes every type: the talker's Setpoint publisher matches it
    verdicts = [line for line in r.stdout.splitlines() if "/flight_recorder [gid" in line]
    assert verdicts and all(line.endswith(": compatible") for line in verdicts), r.stdout


def test_looped_play_delivers_every_pass_to_a_live_subscription(bag_talker, ns, tmp_path):
    node, t, cfg = bag_talker
    path = tmp_path / "f.mcap"
    with Node("rec", config=cfg_session(cfg)) as rnode:
        rec = BagRecorder(rnode, path, [f"/{ns}/setpoint"]).start()
        rnode.spin_until(lambda: rec.counters.written >= 30, 20.0)
        rec.close()
    t.stop.set()
    t.thread.join()
    recorded = {json.loads(r.message.data)["header"]["seq"] for r in iter_records(path)
                if isinstance(r, Record) and r.channel.topic == f"/{ns}/setpoint"}
    n = len(recorded)
    assert n >= 30
    got: list[tuple[int, int]] = []
    node.create_subscription(msgs.Setpoint, "setpoint", lambda m, info: got.append((info.publisher_id, m.header.seq)),
                             qos.SETPOINT.replace(depth=1000))
    with Spinning(node), Node("player", config=cfg_session(cfg)) as pnode:
        player = BagPlayer(pnode, path, [f"/{ns}/setpoint"], rate=4.0, loop=True, passes=2)
        c = player.play()
        wait_for(lambda: len(got) >= 2 * n, 5.0)
        player.close()
    assert c.loops == 1, "two passes"
    by_pub: dict[int, set[int]] = {}
    for pid, seq in got:
        by_pub.setdefault(pid, set()).add(seq)
    # Same sequence numbers twice: without a new publisher id per pass the second would be dropped
    # as duplicates. Loopback may lose a sample or two (best effort): most of each pass arrives.
    assert len(by_pub) == 2, by_pub.keys()
    assert all(len(seqs) >= 0.8 * n and seqs <= recorded for seqs in by_pub.values())
    assert len(got) >= 1.6 * n


def test_publishers_of_one_topic_replay_each_with_its_own_qos(ns, tmp_path):
    listen, connect = linked_configs()
    path = tmp_path / "mixed.mcap"
    kept = QoSProfile(ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL, HistoryPolicy.KEEP_LAST, 5)
    fast = QoSProfile(ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST, 1)
    with Node("pubs", namespace=ns, config=listen) as pnode, Node("rec", config=connect) as rnode:
        a = pnode.create_publisher(msgs.Setpoint, "mixed", kept)
        for i in range(5):
            a.publish(msgs.Setpoint(msgs.Header.now(seq=i), x=1.0))
        with Spinning(rnode):
            rec = BagRecorder(rnode, path, [f"/{ns}/mixed"]).start()
            assert wait_for(lambda: rec.counters.written >= 5, 10.0), "transient local: the kept samples arrive"
            # A VOLATILE publisher joins: the TRANSIENT_LOCAL request would block it, so the recorder asks again.
            b = pnode.create_publisher(msgs.Setpoint, "mixed", fast)
            assert wait_for(lambda: rec.tap_counters.resubscribed >= 1, 10.0)
            for i in range(5, 60):
                (a if i % 2 else b).publish(msgs.Setpoint(msgs.Header.now(seq=i), x=2.0 if i % 2 else 3.0))
                time.sleep(0.01)
            assert wait_for(lambda: rec.counters.written >= 40, 10.0)
            rec.close()
        ids = {a.publisher_id: kept, b.publisher_id: fast}
        raw = _summary_topics(path)[f"/_zr/raw/{ns}/mixed"]
        assert {int(c.metadata["zr.publisher"], 16) for c in raw} == set(ids)
        for c in raw:
            assert decode_qos(c.metadata["zr.qos"]) == ids[int(c.metadata["zr.publisher"], 16)]
        xs = {json.loads(r.message.data)["x"] for r in iter_records(path)
              if isinstance(r, Record) and r.channel.topic == f"/{ns}/mixed"}
        assert xs == {1.0, 2.0, 3.0}, "both publishers recorded"
        pnode.destroy_publisher(a)
        pnode.destroy_publisher(b)
        with Node("player", config=connect) as plnode:
            player = BagPlayer(plnode, path, rate=20.0)
            player.play()
            # The watcher sees the replayed publishers in the graph: each original id, each its own QoS.
            def replayed() -> dict[int, QoSProfile]:
                pubs = pnode.graph.endpoints(f"{ns}/mixed", EndpointType.PUBLISHER)
                return {e.endpoint_gid: e.qos_profile for e in pubs if e.node_name == plnode.get_name()}
            assert wait_for(lambda: len(replayed()) == 2, 10.0)
            assert replayed() == ids
            assert {q for _, q, _ in player._pubs.values()} == {kept, fast}
            player.close()


def test_record_exclude_and_domain(bag_talker, ns, tmp_path):
    _node, _t, talker_cfg = bag_talker
    # Another system on the same network, in domain 7; the recorders link to both systems.
    base = cfg_session(talker_cfg)
    other_endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "both.json5"
    cfg.write_text(json.dumps(dataclasses.replace(base, connect=[*base.connect, other_endpoint]).to_json5()))
    with Node("other", namespace=ns, config=dataclasses.replace(base, listen=[other_endpoint], domain=7)) as other:
        pub = other.create_publisher(VehicleState, "elsewhere")
        stop = threading.Event()

        def run() -> None:
            while not stop.is_set():
                pub.publish(VehicleState(msgs.Header.now(), mode="HOLD"))
                time.sleep(0.05)
        th = threading.Thread(target=run, daemon=True)
        th.start()
        try:
            excl, dom = tmp_path / "excl.mcap", tmp_path / "dom.mcap"
            procs = [subprocess.Popen([*CLI, "bag", "record", "--zenoh", str(cfg), "-a", "--duration", "3",
                                       "--exclude", "setpoint$", "-o", str(excl)], cwd=ROOT, text=True,
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT),
                     subprocess.Popen([*CLI, "bag", "record", "--zenoh", str(cfg), "-a", "--duration", "3",
                                       "--domain", "7", "-o", str(dom)], cwd=ROOT, text=True,
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT)]
            outs = [p.communicate(timeout=60)[0] for p in procs]
            assert [p.returncode for p in procs] == [0, 0], outs
        finally:
            stop.set()
            th.join()
    t_excl, t_dom = _summary_topics(excl), _summary_topics(dom)
    assert f"/{ns}/state" in t_excl and f"/{ns}/setpoint" not in t_excl and f"/{ns}/setpoint/pose" not in t_excl
    assert f"/{ns}/elsewhere" not in t_excl, "domain 0 does not see domain 7"
    assert f"/{ns}/elsewhere" in t_dom and f"/{ns}/state" not in t_dom and f"/{ns}/setpoint" not in t_dom


def test_image_slices_are_a_view_and_raw_bytes_not_json_unless_asked(ns, tmp_path):
    listen, connect = linked_configs()
    with Node("cam", namespace=ns, config=listen) as cnode, Node("rec", config=connect) as rnode:
        camera = ImagePublisher(cnode, "image", qos.IMAGE, quality=60)
        with Spinning(rnode):
            lean = BagRecorder(rnode, tmp_path / "lean.mcap", [f"/{ns}/image"]).start()
            full = BagRecorder(rnode, tmp_path / "full.mcap", [f"/{ns}/image"], slice_json=True).start()
            assert wait_for(lambda: len(lean.subscribed) == len(full.subscribed) == 1, 10.0)
            frame = np.zeros((120, 160, 3), dtype=np.uint8)
            for i in range(30):
                frame[:, :, 0] = i * 8
                camera.publish(frame)
                time.sleep(0.03)
            assert wait_for(lambda: lean.counters.views_written >= 10 and full.counters.views_written >= 10, 10.0)
            lean.close()
            full.close()
    t_lean, t_full = _summary_topics(tmp_path / "lean.mcap"), _summary_topics(tmp_path / "full.mcap")
    assert f"/{ns}/image" not in t_lean and lean.counters.bulk_not_json > 0
    assert f"/{ns}/image/image" in t_lean and f"/_zr/raw/{ns}/image" in t_lean, "the frames and the bytes are kept"
    assert f"/{ns}/image" in t_full and full.counters.written > 0
    assert (tmp_path / "lean.mcap").stat().st_size < (tmp_path / "full.mcap").stat().st_size


def test_bytes_that_are_no_envelope_are_counted_and_the_recording_goes_on(ns, tmp_path):
    listen, connect = linked_configs()
    path = tmp_path / "g.mcap"
    with Node("src", namespace=ns, config=listen) as snode, Node("rec", config=connect) as rnode, Spinning(rnode):
        pub = snode.create_publisher(msgs.Setpoint, "sp")
        rec = BagRecorder(rnode, path, [f"/{ns}/sp"]).start()
        assert wait_for(lambda: f"/{ns}/sp" in rec.subscribed, 10.0)
        time.sleep(0.3)     # the subscription's Zenoh subscriber reaches the source's session
        for i in range(20):
            snode.session.put(f"{ns}/sp", b"\x00garbage" * i)    # a peer writing junk on the topic's key
            pub.publish(msgs.Setpoint(msgs.Header.now(seq=i), x=float(i)))
            time.sleep(0.01)
        assert wait_for(lambda: rec.counters.written >= 15, 10.0)
        rec.close()
    assert rec.tap_counters.sub_malformed >= 15
    with open(path, "rb") as f:
        meta = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    assert int(meta["zenoh_robot.recording"]["sub_malformed"]) == rec.tap_counters.sub_malformed
    xs = [json.loads(r.message.data)["x"] for r in iter_records(path)
          if isinstance(r, Record) and r.channel.topic == f"/{ns}/sp"]
    assert xs == sorted(xs) and len(xs) >= 15


def test_fec_image_shares_become_whole_jpeg_frames_in_the_log(ns, tmp_path):
    import zfec  # noqa: F401  (a dev dependency: missing is a failure)

    from zenoh_robot.image.fec import FecImagePublisher

    listen, connect = linked_configs()
    path = tmp_path / "fec.mcap"
    with Node("cam", namespace=ns, config=listen) as cnode, Node("rec", config=connect) as rnode, Spinning(rnode):
        camera = FecImagePublisher(cnode, "image", loss=0.2)
        rec = BagRecorder(rnode, path, [f"/{ns}/image"]).start()
        assert wait_for(lambda: len(rec.subscribed) == 1, 10.0)
        time.sleep(0.3)
        rng = np.random.default_rng(1)
        for _ in range(15):
            camera.publish(rng.integers(0, 255, (96, 128, 3), dtype=np.uint8))
            time.sleep(0.03)
        assert wait_for(lambda: rec.counters.views_written >= 10, 10.0), rec.counters
        rec.close()
    topics = _summary_topics(path)
    assert f"/{ns}/image" not in topics, "the shares are not copied as base64 JSON"
    assert f"/_zr/raw/{ns}/image" in topics
    with open(path, "rb") as f:
        frames = [m for _, _, m in make_reader(f).iter_messages(topics=[f"/{ns}/image/image"])]
    assert len(frames) >= 10
    assert all(b"\xff\xd8\xff" in m.data for m in frames), "each view holds a whole JPEG (start of image marker)"
