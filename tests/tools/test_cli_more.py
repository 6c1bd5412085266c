"""The first CLI half's verbs still untested: echo --field/--csv/--msg, bw, delay, type, find,
--qos FILE.yaml:PROFILE, hz on a sliced image stream, and the statistics key convention.

The talker of test_cli_topic (its TALKER script) serves this module too (its own process: module scope).
"""
from __future__ import annotations

import re
import secrets
import subprocess
import time

from cli_helpers import CLI, TOPIC_TALKER, cli
from conftest import ROOT, Lines, python_proc, wait_for
from conftest import kill_process as _stop

from zenoh_robot import Node, ReliabilityPolicy, msgs, qos
from zenoh_robot.topic_statistics import default_statistics_key

TALKER = TOPIC_TALKER   # conftest's talker fixture runs it (test_cli_topic's talker)


def _echo(*args: str) -> subprocess.CompletedProcess[str]:
    """``topic echo`` to its end; if it never ends, what the graph showed then (one CI rehearsal's echo of the
    talker's setpoints waited 60 s: whether the publisher was on the graph tells a lost match from no data)."""
    try:
        return cli("topic", "echo", *args, timeout=60)
    except subprocess.TimeoutExpired:
        graph = cli("topic", "info", "-v", args[0], timeout=30)
        raise AssertionError(f"topic echo {' '.join(args)} never ended; topic info -v then:\n"
                             f"{graph.stdout}{graph.stderr}") from None


def test_echo_field_prints_one_value_per_message(talker):
    # One line per message, no `---` between them (issue #39): what a shell loop or `sort` reads.
    out = _echo(f"/{talker}/setpoint", "--field", "x", "--count", "2")
    assert out.returncode == 0, out.stderr
    assert out.stdout == "1.5\n1.5\n"
    out = _echo(f"/{talker}/chatter", "--field", "data", "--count", "2")
    assert out.returncode == 0, out.stderr
    assert re.fullmatch(r"hello \d+\nhello \d+\n", out.stdout), out.stdout     # no YAML `...`, no `---`
    out = _echo(f"/{talker}/setpoint", "--field", "header", "--once")
    assert out.returncode == 0, out.stderr
    assert re.fullmatch(r"\{stamp: \d+, frame_id: '', seq: \d+\}\n", out.stdout), out.stdout   # a structure: one line
    out = cli("topic", "echo", f"/{talker}/setpoint", "--field", "header.nope", "--once")
    assert out.returncode == 1 and "header.nope" in out.stderr, out


def test_echo_csv_has_a_header_then_one_line_per_message(talker):
    out = cli("topic", "echo", f"/{talker}/setpoint", "--csv", "--count", "3")
    assert out.returncode == 0, out.stderr
    header, *rows = out.stdout.splitlines()
    assert header == "header.stamp,header.frame_id,header.seq,x,y,z,yaw,is_velocity"
    assert len(rows) == 3
    ys = [float(r.split(",")[4]) for r in rows]
    assert all(r.split(",")[3] == "1.5" for r in rows) and ys == sorted(ys), rows   # y counts up


def test_echo_msg_file_decodes_a_type_unknown_here(talker, tmp_path):
    msg = tmp_path / "Secret.msg"
    msg.write_text("int64 code  # what the talker's test_msgs/Secret holds\n")
    out = cli("topic", "echo", f"/{talker}/secret", "--msg", str(msg), "--once")
    assert out.returncode == 0, out.stderr
    assert out.stdout == "code: 42\n---\n"
    assert "not registered here" not in out.stderr


def test_bw_reports_bytes_per_second(talker):
    out = cli("topic", "bw", f"/{talker}/chatter", "--duration", "3")
    assert out.returncode == 0, out.stderr
    m = re.findall(r"^([0-9.]+) (B|KB)/s from (\d+) messages$", out.stdout, re.M)
    assert m, out.stdout
    rate, unit, count = m[-1]
    assert int(count) >= 10
    # ~20 "hello N" strings a second, each an envelope of some tens of bytes
    assert unit == "KB" or 200 < float(rate) < 1000 * 20, out.stdout
    assert re.search(r"^\tMessage size mean: [0-9.]+ B min: [0-9.]+ B max: [0-9.]+ B$", out.stdout, re.M)


def test_delay_of_stamped_and_of_unstamped_messages(talker):
    out = cli("topic", "delay", f"/{talker}/setpoint", "--duration", "3")
    assert out.returncode == 0, out.stderr
    delays = [float(d) for d in re.findall(r"^average delay: (-?[0-9.]+)$", out.stdout, re.M)]
    # One host: the delivery only (a loaded machine can stretch it; a unit or clock-source error reads years).
    assert delays and abs(delays[-1]) < 5.0, out.stdout
    out = cli("topic", "delay", f"/{talker}/chatter", "--duration", "2")
    assert "messages have no header stamp" in out.stdout, out.stdout


def test_type_and_find(talker):
    out = cli("topic", "type", f"/{talker}/setpoint")
    assert out.returncode == 0 and out.stdout == "zenoh_robot/Setpoint\n", out
    out = cli("topic", "find", "Setpoint")
    assert out.returncode == 0, out.stderr
    assert f"/{talker}/setpoint" in out.stdout.splitlines() and f"/{talker}/chatter" not in out.stdout
    out = cli("topic", "find", "std_msgs/String")
    assert {f"/{talker}/chatter", f"/{talker}/latched"} <= set(out.stdout.splitlines()), out.stdout


def test_pub_with_a_qos_file_profile(ns):
    """`--qos configs/qos/robot_profiles.yaml:state`: the publisher the graph shows has that profile."""
    got: list[str] = []
    proc = subprocess.Popen([*CLI, "topic", "pub", f"/{ns}/state_in", "std_msgs/String", "{data: qos}", "-r", "10",
                             "--duration", "8", "--qos", "configs/qos/robot_profiles.yaml:state"],
                            cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        with Node("inbox", namespace=ns) as node:
            node.create_subscription(msgs.String, "state_in", lambda m: got.append(m.data), 10)
            assert node.spin_until(lambda: bool(got), timeout=8.0), got
            # A sample may arrive before the publisher's graph token does: wait for the graph too.
            assert node.spin_until(lambda: bool(node.get_publishers_info_by_topic(f"/{ns}/state_in")), 5.0)
            pubs = node.get_publishers_info_by_topic(f"/{ns}/state_in")
            assert len(pubs) == 1
            q = pubs[0].qos_profile
            assert (q.reliability, q.depth) == (ReliabilityPolicy.RELIABLE, 1)   # the file's `state` profile
            assert q.priority.name == "INTERACTIVE_HIGH"
    finally:
        _stop(proc)
    bad = cli("topic", "pub", f"/{ns}/x", "String", "{data: x}", "--once", "--qos",
              "configs/qos/robot_profiles.yaml:nope")
    assert bad.returncode == 1 and "has no profile 'nope'; profiles: " in bad.stderr, bad.stderr


IMAGES = r"""
import sys, time
import numpy as np
from zenoh_robot import Node
from zenoh_robot.image.sliced import ImagePublisher
with Node("camera", namespace=sys.argv[1]) as n:
    cam = ImagePublisher(n, "image", slice_rows=16)
    rng = np.random.default_rng(1)
    frame = rng.integers(0, 255, (128, 160, 3), dtype=np.uint8)   # noise: JPEG cannot shrink it away
    print("slices per frame", len(cam.encode(frame)), flush=True)
    t = time.monotonic()
    while True:
        cam.publish(frame)
        t += 0.1                                   # 10 frames a second
        n.spin(max(0.0, t - time.monotonic()))
"""


def test_hz_of_a_sliced_image_stream_counts_frames(ns):
    proc = python_proc("-c", IMAGES, ns)
    try:
        out = Lines(proc)
        assert out.wait_for(r"^slices per frame \d+$"), out.text()
        slices = int(out.lines[0].split()[-1])
        assert slices >= 4, out.text()      # else counting slices and frames would look alike
        res = cli("topic", "hz", f"/{ns}/image", "--duration", "4")
        assert res.returncode == 0, res.stderr
        rates = [float(r) for r in re.findall(r"^average rate: ([0-9.]+)$", res.stdout, re.M)]
        assert rates, res.stdout
        assert 5 < rates[-1] < 15, (rates, slices)          # ~10 frames/s, not ~10 x slices
    finally:
        _stop(proc)


# -- one statistics topic convention ----------------------------------------------------------
def test_gcs_and_companion_statistics_share_the_drone_prefix():
    # the companion: namespace uav1, subscribes uav1/setpoint; the GCS: no namespace, subscribes uav1/sensor
    assert default_statistics_key("uav1", "uav1/setpoint") == "uav1/statistics/setpoint"
    assert default_statistics_key("", "uav1/sensor") == "uav1/statistics/sensor"
    assert default_statistics_key("", "chatter") == "statistics/chatter"


def test_a_root_node_publishes_statistics_under_the_topics_namespace_and_stats_explains_drop(ns):
    proc = subprocess.Popen([*CLI, "stats", "--plain", "--duration", "8"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        out = Lines(proc)
        with Node(f"gcs_{secrets.token_hex(2)}", enable_topic_statistics=True) as gcs, \
                Node("companion", namespace=ns) as comp:
            gcs.create_subscription(msgs.String, f"/{ns}/sensor", lambda m: None, 5)
            pub = comp.create_publisher(msgs.String, "sensor", 5)

            def heard() -> bool:
                pub.publish(msgs.String("s"))
                gcs.spin_once(0.05)
                return any(f"key={ns}/statistics/sensor" in line for line in out.lines)
            assert wait_for(heard, timeout=8.0), out.text()
        assert out.lines[0].startswith("# lost: ") and "drop: samples the subscriber's KEEP_LAST queue overwrote " \
            "before the callback ran: the application was slower than the stream" in out.lines[0], out.lines[0]
        assert not [line for line in out.lines if f"key=statistics/{ns}/" in line]
    finally:
        _stop(proc)


def test_a_healthy_200hz_stream_with_depth_5_drops_nothing(ns):
    """200 Hz, evenly spaced, depth 5, a callback that keeps up: `drop` stays 0 (measured: 0 of 1600
    across processes). The same average rate in bursts of 10 every 50 ms drops ~40 % at depth 5."""
    with Node("fast", namespace=ns) as a, Node("keeper", namespace=ns) as b:
        got: list[int] = []
        sub = b.create_subscription(msgs.Header, "imu", lambda m: got.append(m.seq), qos.SENSOR)
        pub = a.create_publisher(msgs.Header, "imu", qos.SENSOR)
        assert wait_for(lambda: bool(a.get_subscriptions_info_by_topic(f"/{ns}/imu")), 5.0)
        t = time.monotonic()
        for i in range(400):                       # 2 s at 200 Hz
            pub.publish(msgs.Header(seq=i))
            t = max(t + 0.005, time.monotonic())   # a stalled machine slows the stream, never bursts it
            b.spin_once(max(0.0, t - time.monotonic()))
        b.spin_until(lambda: len(got) >= 400, timeout=3.0)
        assert sub.counters.received == 400, sub.counters       # reliable enough on loopback to count
        assert sub.counters.dropped == 0, sub.counters
