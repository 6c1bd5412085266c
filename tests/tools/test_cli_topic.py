"""`zenoh-robot topic ...` and `zenoh-robot stats` against a real publisher in another process.

One talker process (conftest's ``talker`` fixture running TALKER) serves the whole module:
a BEST_EFFORT String stream with a RELIABLE
(so incompatible) subscription beside it, a Setpoint stream, a type the CLI does not
know, a TRANSIENT_LOCAL topic published once at start, and TopicStatistics published by
hand so `stats` is tested apart from the statistics module.
"""
from __future__ import annotations

import re
import signal
import subprocess
import time

import pytest
from cli_helpers import INTERACTIVE_CLI, ROOT, TOPIC_TALKER, cli, cli_seeing
from conftest import Lines, kill_process

from zenoh_robot import (
    DurabilityPolicy,
    EndpointType,
    Node,
    QoSProfile,
    TopicEndpointInfo,
    check_compatibility,
    msgs,
    qos,
)
from zenoh_robot.tools.cli.topic import adapted_qos

TALKER = TOPIC_TALKER   # conftest's talker fixture runs it


def test_list_shows_topics_and_types(talker):
    ns = talker
    out = cli_seeing(ns, "topic", "list")
    assert out.returncode == 0, out.stderr
    assert f"/{ns}/chatter" in out.stdout.splitlines()
    out = cli_seeing(ns, "topic", "list", "-v")
    assert out.returncode == 0, out.stderr
    assert f"/{ns}/chatter [std_msgs/String] 1 publisher, 1 subscription" in out.stdout.splitlines()
    assert f"/{ns}/setpoint [zenoh_robot/Setpoint] 1 publisher, 0 subscriptions" in out.stdout.splitlines()


def test_info_shows_qos_and_compatibility(talker):
    ns = talker
    out = cli("topic", "info", f"/{ns}/chatter")
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[:3] == ["Type: std_msgs/String", "Publisher count: 1", "Subscription count: 1"]
    assert "1 incompatible publisher/subscription pair" in out.stdout
    out = cli("topic", "info", f"/{ns}/chatter", "-v")
    assert out.returncode == 0, out.stderr
    text = out.stdout
    for expected in ("Node name: talker", f"Node namespace: /{ns}", "Endpoint type: PUBLISHER",
                     "Reliability: BEST_EFFORT", "History (depth): KEEP_LAST (5)", "Durability: VOLATILE",
                     "Deadline: infinite", "Priority: DATA_HIGH", "Endpoint type: SUBSCRIPTION",
                     "Reliability: RELIABLE"):
        assert expected in text, text
    verdicts = [line for line in text.splitlines() if "] -> " in line]
    assert len(verdicts) == 1, text
    assert "incompatible (RELIABILITY)" in verdicts[0] and "BEST_EFFORT" in verdicts[0]


def test_echo_prints_decoded_samples(talker):
    out = cli("topic", "echo", f"/{talker}/setpoint", "--count", "2")
    assert out.returncode == 0, out.stderr
    docs = out.stdout.split("---\n")
    assert len(docs) == 3 and docs[2] == "", out.stdout     # two samples, each ended by ---
    for doc in docs[:2]:
        assert "x: 1.5" in doc and "header:" in doc and "  frame_id: ''" in doc, doc


def test_echo_of_an_unknown_type_prints_raw_fields(talker):
    out = cli("topic", "echo", f"/{talker}/secret", "--once")
    assert out.returncode == 0, out.stderr
    assert "type: test_msgs/Secret" in out.stdout and "- 42" in out.stdout, out.stdout
    assert "not registered here" in out.stderr


def test_echo_hears_samples_kept_before_it_started(talker):
    out = cli("topic", "echo", f"/{talker}/latched", "--once", "--duration", "10")
    assert out.returncode == 0, out.stderr
    assert out.stdout == "data: kept for late joiners\n---\n"


def test_adapted_qos_is_compatible_with_every_publisher():
    pubs = [_endpoint(q) for q in [*qos.PRESETS.values(), QoSProfile(deadline=0.1, liveliness_lease_duration=0.5),
                                   QoSProfile(liveliness="manual_by_topic", liveliness_lease_duration=1.0)]]
    requested = adapted_qos(pubs)
    assert requested.durability is DurabilityPolicy.VOLATILE
    assert all(check_compatibility(p.qos_profile, requested).compatible for p in pubs)
    keeping = [_endpoint(qos.CONFIGURATION), _endpoint(qos.CONFIGURATION.replace(reliability="best_effort"))]
    requested = adapted_qos(keeping)
    assert requested.durability is DurabilityPolicy.TRANSIENT_LOCAL
    assert all(check_compatibility(p.qos_profile, requested).compatible for p in keeping)


def _endpoint(profile: QoSProfile) -> TopicEndpointInfo:
    return TopicEndpointInfo("n", "/", "/t", "std_msgs/String", "0", EndpointType.PUBLISHER, 1, profile)


def test_hz_reports_the_publisher_rate(talker):
    out = cli("topic", "hz", f"/{talker}/chatter", "--duration", "3")
    assert out.returncode == 0, out.stderr
    rates = [float(r) for r in re.findall(r"^average rate: ([0-9.]+)$", out.stdout, re.M)]
    assert rates, out.stdout
    assert 5 < rates[-1] < 60, out.stdout
    assert re.search(r"^\tmin: [0-9.]+s max: [0-9.]+s std dev: [0-9.]+s window: \d+$", out.stdout, re.M)


def test_pub_once_reaches_a_subscription(talker):
    got: list[str] = []
    with Node("inbox", namespace=talker) as node:
        node.create_subscription(msgs.String, "inbox", lambda m: got.append(m.data), 10)
        out = cli("topic", "pub", f"/{talker}/inbox", "std_msgs/String", "{data: hi there}", "--once",
                  "--max-wait", "5")
        assert out.returncode == 0, out.stderr
        assert "publishing #1: {data: hi there}" in out.stdout
        assert node.spin_until(lambda: got == ["hi there"], timeout=5.0), got


def test_stats_plain_prints_a_row(talker):
    ns = talker
    out = cli("stats", f"/{ns}/chatter", "--plain", "--duration", "2")
    assert out.returncode == 0, out.stderr
    rows = [line for line in out.stdout.splitlines() if line.startswith(f"/{ns}/chatter ")]
    assert rows, out.stdout
    row = rows[-1]
    for expected in (f"node=/{ns}/listener", "age_ms avg=1.50 min=0.50 max=3.00", "period_ms avg=50.00",
                     "rate_hz=20.0", "samples=20", "lost=2", "dropped=1", f"key={ns}/statistics/chatter"):
        assert expected in row, row


@pytest.mark.parametrize("args, message", [
    (["topic", "pub", "/{ns}/inbox", "NoSuchType", "{data: x}"], "unknown message type 'NoSuchType'"),
    (["topic", "pub", "/{ns}/inbox", "String", "{data: x"], "not valid YAML"),
    (["topic", "pub", "/{ns}/inbox", "String", "[1, 2]"], "must be a YAML mapping"),
    (["topic", "pub", "/{ns}/inbox", "String", "{text: x}"], "has no field(s) ['text']"),
    (["topic", "pub", "/{ns}/inbox", "String", "{data: 5}"], "expected string, got int"),
    (["topic", "pub", "/{ns}/inbox", "String", "{data: x}", "--rate", "0"], "--rate must be > 0"),
    (["topic", "info", "/{ns}/nothing", "--timeout", "1"], "topic /{ns}/nothing not found"),
    (["topic", "echo", "/{ns}/nothing", "--duration", "1"], "/{ns}/nothing did not appear"),
])
def test_errors_are_one_line(ns, args, message):
    out = cli(*[a.replace("{ns}", ns) for a in args])
    assert out.returncode == 1, (out.stdout, out.stderr)
    assert "Traceback" not in out.stderr
    errors = [line for line in out.stderr.splitlines() if line.startswith("zenoh-robot ")]
    assert len(errors) == 1, out.stderr
    assert message.replace("{ns}", ns) in errors[0], errors[0]
    assert [line for line in out.stderr.splitlines() if not line.startswith("waiting for ")] == errors


@pytest.mark.parametrize("args, first_output", [
    (["topic", "echo", "/{ns}/chatter"], "^---$"),
    (["stats", "/{ns}/chatter"], "^/{ns}/chatter node="),   # stdout is a pipe: plain lines
])
def test_ctrl_c_exits_quietly(talker, args, first_output):
    proc = subprocess.Popen([*INTERACTIVE_CLI, *[a.replace("{ns}", talker) for a in args]], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        out = Lines(proc)
        assert out.wait_for(first_output.replace("{ns}", talker)), out.text()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0, out.text()
        time.sleep(0.1)   # the reader thread takes the last lines
        assert "Traceback" not in out.text() and "KeyboardInterrupt" not in out.text()
    finally:
        kill_process(proc)
