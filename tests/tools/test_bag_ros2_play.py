"""`zenoh-robot bag play` puts a bag's ROS 2 `cdr` channels back on the ROS 2 wire: rmw_zenoh's data key
(type and RIHS01 hash), its `MP` token and its 33-byte attachment, with the recording's spacing.

Real parts: ROS 2 wire Nodes on loopback sockets, `bag record` and `bag play` as their own processes
(the CLI), the mcap reader and writer. Round trip: a PoseStamped and an Imu publisher are recorded, the
recording played, and a ROS 2 wire subscriber gets every recorded message, equal, in order. A
rosbag2-shaped file (no zenoh-robot metadata) of a type the player's process has never heard of plays
from its schema text alone; channels that cannot be played get one line each.
"""
from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path
from typing import Any

from conftest import CLI, ROOT, free_port, fresh_domain, record_ros2_talker
from mcap.reader import make_reader
from mcap.writer import Writer

from zenoh_robot import Node, QoSProfile, SessionConfig
from zenoh_robot.graph import EndpointType, TopicEndpointInfo
from zenoh_robot.message import type_support
from zenoh_robot.ros2 import cdr_codec, load_ros2_msg, ros2_type
from zenoh_robot.wire import ros2_wire

POSE, IMU = "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu"


def _config(port: int) -> SessionConfig:
    return SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, shared_memory=False)


def _session_flags(domain: int, port: int) -> list[str]:
    return ["--ros-domain-id", str(domain), "-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0"]


class Listener:
    """A ROS 2 wire subscriber per topic, spinning on a thread; what arrived, with its receive time."""

    def __init__(self, node: Node, topics: dict[str, type]) -> None:
        self.got: dict[str, list[tuple[Any, int]]] = {t: [] for t in topics}
        self.publishers: list[TopicEndpointInfo] = []
        node.graph.listeners.append(self._on_graph)
        for topic, cls in topics.items():
            node.create_subscription(cls, topic, lambda m, info, t=topic: self.got[t].append(
                (m, info.received_stamp_ns)), QoSProfile(depth=1000))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=node.spin_until, args=(self._stop.is_set, 120.0), daemon=True)
        self._thread.start()

    def _on_graph(self, appeared: bool, info: TopicEndpointInfo) -> None:
        if appeared and info.endpoint_type is EndpointType.PUBLISHER:
            self.publishers.append(info)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


def _recorded(path: Path) -> tuple[dict[str, list[Any]], dict[str, int]]:
    """Each cdr channel's messages decoded by the type's codec, and its span of log times (ns)."""
    out: dict[str, list[Any]] = {}
    times: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "cdr":
                continue
            cls = ros2_type(schema.name)
            out.setdefault(channel.topic, []).append(type_support(cls).decode(cdr_codec(cls).deserialize(message.data)))
            times.setdefault(channel.topic, []).append(message.log_time)
    return out, {t: v[-1] - v[0] for t, v in times.items()}


def test_bag_play_puts_a_ros2_recording_back_on_the_ros2_wire(tmp_path: Path) -> None:
    domain = fresh_domain()
    T = {n: ros2_type(n) for n in (POSE, IMU)}
    out = tmp_path / "ros2.mcap"
    r = record_ros2_talker(out, domain, 3)
    assert r.returncode == 0, r.stderr
    recorded, spans = _recorded(out)
    assert len(recorded.get("/zr/pose", [])) > 20 and len(recorded.get("/zr/imu", [])) > 20, r.stderr

    # The talker is gone: whatever arrives now comes from the bag, played twice as fast.
    port = free_port()
    with Node("listener", namespace="zr", config=_config(port), wire=ros2_wire(domain)) as node:
        listener = Listener(node, {"/zr/pose": T[POSE], "/zr/imu": T[IMU]})
        try:
            p = subprocess.run([*CLI, "bag", "play", str(out), "--rate", "2", *_session_flags(domain, port)],
                               cwd=ROOT, capture_output=True, text=True, timeout=60)
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and any(
                    len(listener.got[t]) < len(recorded[t]) for t in listener.got):
                time.sleep(0.05)
        finally:
            listener.close()
    assert p.returncode == 0, p.stderr
    assert "cannot play" not in p.stderr, p.stderr     # the JSON-less ROS 2 bag: every channel plays
    for topic in ("/zr/pose", "/zr/imu"):
        got = [m for m, _t in listener.got[topic]]
        assert got == recorded[topic], (topic, len(got), len(recorded[topic]), p.stderr)
        stamps = [t for _m, t in listener.got[topic]]
        # Spread over the recording's span at --rate 2, not sent in one burst: a lower bound with a wide
        # margin (load stretches a replay; only a long stall on its very first sample could squeeze it).
        assert stamps[-1] - stamps[0] >= 0.5 * spans[topic] / 2, (stamps[-1] - stamps[0], spans[topic])
    # The player announced ROS 2 publishers of the recorded types, with ROS 2's hashes.
    announced = {(i.topic_name, i.topic_type, i.topic_type_hash) for i in listener.publishers}
    for topic, name in (("/zr/pose", POSE), ("/zr/imu", IMU)):
        assert (topic, name, type_support(T[name]).hash) in announced, announced


PROBE_TEXT = """# A type no process but this test's has: the player learns it from the bag
uint8 MODE_IDLE=0
uint8 MODE_BUSY=1
std_msgs/Header header
zr_bagplay/Inner[] items
string label
float64[3] v
uint8 mode
"""
INNER_TEXT = """int32 a
string b  # a comment, as rosbag2 keeps them
"""
SEP = "=" * 80


def _rosbag2_schema() -> bytes:
    # As rosbag2 writes a ros2msg schema: the type, then every type it uses after a separator
    return "\n".join([PROBE_TEXT.rstrip("\n"), SEP, "MSG: zr_bagplay/Inner", INNER_TEXT.rstrip("\n"), SEP,
                      "MSG: std_msgs/Header", "builtin_interfaces/Time stamp", "string frame_id", SEP,
                      "MSG: builtin_interfaces/Time", "int32 sec", "uint32 nanosec", ""]).encode()


OFFERED_QOS = """- history: keep_last
  depth: 50
  reliability: reliable
  durability: volatile
"""


def _write_rosbag2_file(path: Path, probes: list[Any], *, bad_channels: bool) -> None:
    Probe = type(probes[0])
    codec = cdr_codec(Probe)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("zr_bagplay/msg/Probe", "ros2msg", _rosbag2_schema())
        cid = w.register_channel("/zr/probe", "cdr", sid, {"offered_qos_profiles": OFFERED_QOS})
        t0 = 1_700_000_000_000_000_000
        for i, msg in enumerate(probes):
            w.add_message(cid, t0 + i * 20_000_000, codec.serialize(type_support(Probe).encode(msg)),
                          t0 + i * 20_000_000, i)
        if bad_channels:
            bad = {
                "/zr/idl": w.register_schema("zr_bagplay/msg/Idl", "ros2idl", b"module zr_bagplay { };"),
                "/zr/broken": w.register_schema("zr_bagplay/msg/Broken", "ros2msg", b"flaot64[ x\n"),
                "/zr/lying": w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n"),
            }
            for topic, schema_id in bad.items():
                ch = w.register_channel(topic, "cdr", schema_id, {})
                for i in range(3):
                    w.add_message(ch, t0 + i * 20_000_000, b"\x00\x01\x00\x00\x01", t0 + i * 20_000_000, i)
        w.finish()


def test_bag_play_learns_an_unknown_type_from_a_rosbag2_schema(tmp_path: Path) -> None:
    domain = fresh_domain()
    load_ros2_msg(INNER_TEXT, "zr_bagplay/msg/Inner")
    Probe = load_ros2_msg(PROBE_TEXT.replace("zr_bagplay/Inner", "zr_bagplay/msg/Inner"), "zr_bagplay/msg/Probe")
    Inner, Header, Time = (ros2_type(n) for n in ("zr_bagplay/msg/Inner", "std_msgs/msg/Header",
                                                  "builtin_interfaces/msg/Time"))
    probes = [Probe(header=Header(stamp=Time(sec=i, nanosec=9), frame_id="probe"),
                    items=[Inner(a=i * k, b=f"item{k}") for k in range(i % 4)],
                    label=f"probe {i}", v=[float(i), -1.5, 1e9], mode=i % 2) for i in range(40)]
    bag = tmp_path / "rosbag2.mcap"
    _write_rosbag2_file(bag, probes, bad_channels=True)
    port = free_port()
    with Node("listener", config=_config(port), wire=ros2_wire(domain)) as node:
        listener = Listener(node, {"/zr/probe": Probe})
        try:
            # The player is another process: it has never registered zr_bagplay's types.
            p = subprocess.run([*CLI, "bag", "play", str(bag), "--rate", "4", *_session_flags(domain, port)],
                               cwd=ROOT, capture_output=True, text=True, timeout=60)
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and len(listener.got["/zr/probe"]) < len(probes):
                time.sleep(0.05)
        finally:
            listener.close()
    assert p.returncode == 0, p.stderr
    assert [m for m, _t in listener.got["/zr/probe"]] == probes, (len(listener.got["/zr/probe"]), p.stderr)
    assert ("/zr/probe", "zr_bagplay/msg/Probe", type_support(Probe).hash) in {
        (i.topic_name, i.topic_type, i.topic_type_hash) for i in listener.publishers}
    # One line per channel it cannot play (each has 3 messages), saying why.
    lines = [x for x in p.stderr.splitlines() if x.startswith("cannot play ")]
    assert len(lines) == 3, p.stderr
    idl, broken, lying = (next(x for x in lines if x.startswith(f"cannot play {t} ")) for t in
                          ("/zr/idl", "/zr/broken", "/zr/lying"))
    assert "only ros2msg" in idl, idl
    assert "does not parse" in broken, broken
    assert "not std_msgs/msg/Float64 CDR" in lying, lying
    assert "published 40 samples on 1 topics" in p.stderr, p.stderr


def test_bag_play_of_nothing_playable_is_an_error(tmp_path: Path) -> None:
    bag = tmp_path / "idl.mcap"
    with open(bag, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        ch = w.register_channel("/zr/idl", "cdr", w.register_schema("zr_bagplay/msg/Idl", "ros2idl", b"x"), {})
        w.add_message(ch, 1, b"\x00\x01\x00\x00", 1, 0)
        w.finish()
    p = subprocess.run([*CLI, "bag", "play", str(bag), "--ros-domain-id", "7", "-l", "tcp/127.0.0.1:0"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert p.returncode == 1, p.stderr
    assert "cannot play /zr/idl (cdr, schema ros2idl zr_bagplay/msg/Idl): schema encoding 'ros2idl'" in p.stderr
    assert "nothing played" in p.stderr, p.stderr


def test_bag_player_loops_a_ros2_channel_as_new_samples_and_names_each_bad_channel_once(tmp_path: Path) -> None:
    from zenoh_robot.tools.bag.play import BagPlayer

    domain = fresh_domain()
    load_ros2_msg(INNER_TEXT, "zr_bagplay/msg/Inner")
    Probe = load_ros2_msg(PROBE_TEXT.replace("zr_bagplay/Inner", "zr_bagplay/msg/Inner"), "zr_bagplay/msg/Probe")
    Header = ros2_type("std_msgs/msg/Header")
    probes = [Probe(header=Header(frame_id=f"p{i}"), label=str(i)) for i in range(10)]
    bag = tmp_path / "loop.mcap"
    _write_rosbag2_file(bag, probes, bad_channels=True)
    port = free_port()
    player_config = SessionConfig(connect=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, shared_memory=False)
    lines: list[str] = []
    with Node("listener", config=_config(port), wire=ros2_wire(domain)) as node, \
            Node("player", config=player_config, wire=ros2_wire(domain)) as player_node:
        listener = Listener(node, {"/zr/probe": Probe})
        player = BagPlayer(player_node, bag, rate=10.0, loop=True, passes=2, on_unplayable=lines.append)
        try:
            counters = player.play()
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and len(listener.got["/zr/probe"]) < 2 * len(probes):
                time.sleep(0.05)
        finally:
            player.close()
            listener.close()
    # The second pass goes on with the sequence numbers: the subscription takes it as new samples.
    assert [m for m, _t in listener.got["/zr/probe"]] == probes * 2
    assert (counters.loops, counters.published, counters.ros2_published) == (1, 20, 20)
    assert len(lines) == 3 and len(counters.unplayable) == 3, lines     # once per channel, not per pass
