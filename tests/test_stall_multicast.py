"""The resilient setpoint stream must never stall on the multicast transport (docs/zenoh-multicast-stall.md).

Zenoh 1.10's UDP multicast transport stops sending for good when express samples go out in
quick succession (a setpoint and its 3 ms repeats), more often when other processes load the
CPU. The stall hit a run now and then, so one run proves nothing: this test runs many short
GCS -> drone setpoint streams at once (each pair in its own namespaces, joined by a veth with
no loss), under two busy-looping CPU hogs, and asserts that every one delivered to the end.
With express on the wire (the old setting) it fails in most runs.

Run as a script it is one side of a run: ``python test_stall_multicast.py pub|sub IFACE SECONDS``.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import pytest
from conftest import last_json, wait_ready

ROOT = Path(__file__).resolve().parents[1]
RUNS = 8            # at once: the stall needs load, and the runs are part of it
SECONDS = 4.0
RATE_HZ = 10.0


def _peer(role: str, iface: str, seconds: float) -> None:
    from zenoh_robot import Node
    from zenoh_robot.msgs import Header, Setpoint
    from zenoh_robot.session_config import SessionConfig
    from zenoh_robot.tools.stream_profiles import stream_profile

    qos = stream_profile("resilient").qos["setpoint"]
    with Node(f"stall_{role}", config=SessionConfig.resilient(iface)) as node:
        if role == "pub":
            pub = node.create_publisher(Setpoint, "stall/setpoint", qos)
            print("READY", flush=True)
            sys.stdin.readline()          # the subscriber is up: start
            n = int(seconds * RATE_HZ)
            t0 = time.monotonic()
            for i in range(n):
                pub.publish(Setpoint(Header.now(seq=i), x=float(i)))
                time.sleep(max(0.0, t0 + (i + 1) / RATE_HZ - time.monotonic()))
            print(json.dumps({"sent": n, "express_on_wire": pub.express_on_wire}), flush=True)
            time.sleep(0.5)
        else:
            seqs: set[int] = set()
            node.create_subscription(Setpoint, "stall/setpoint", lambda m: seqs.add(m.header.seq),
                                     qos.replace(depth=100))
            print("READY", flush=True)
            node.spin(timeout=seconds + 3.0)
            print(json.dumps({"unique": len(seqs), "last": max(seqs, default=-1)}), flush=True)


@pytest.fixture
def cpu_hogs():
    """Two busy loops at nice 5, as in the outside harness that first saw the stall."""
    hogs = [subprocess.Popen(["nice", "-n", "5", sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    yield
    for h in hogs:
        h.kill()
        h.wait()


@pytest.mark.netns
def test_resilient_setpoints_never_stall_on_multicast_under_cpu_load(cpu_hogs: None) -> None:
    from conftest import skip_unless_required

    from zenoh_robot.tools.experiment.netns import LossyLink, unavailable_reason

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"multicast stall test: network namespaces are unavailable: {reason}")
    me = str(Path(__file__).resolve())
    with ExitStack() as stack:
        links = [stack.enter_context(LossyLink(loss_pct=0)) for _ in range(RUNS)]
        subs, pubs = [], []
        for link in links:
            subs.append(subprocess.Popen(link.exec_in("drone") + [sys.executable, me, "sub", link.dev("drone"),
                                         str(SECONDS)], stdout=subprocess.PIPE, text=True, cwd=ROOT))
            pubs.append(subprocess.Popen(link.exec_in("gcs") + [sys.executable, me, "pub", link.dev("gcs"),
                                         str(SECONDS)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                         cwd=ROOT))
        for p in subs + pubs:
            assert p.stdout is not None and wait_ready(p)
        time.sleep(1.0)       # a few Join rounds (every 250 ms): the peers know each other
        for p in pubs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        results = []
        for sub, pub in zip(subs, pubs, strict=True):
            pub_out, _ = pub.communicate(timeout=SECONDS + 30)
            sub_out, _ = sub.communicate(timeout=SECONDS + 30)
            assert pub.returncode == 0 and sub.returncode == 0, (pub_out, sub_out)
            results.append((last_json(pub_out), last_json(sub_out)))
    assert all(not p["express_on_wire"] for p, _ in results), "express reached a multicast session"
    stalled = [(p["sent"], s) for p, s in results if s["unique"] < 0.9 * p["sent"] or s["last"] < p["sent"] - 3]
    assert not stalled, f"{len(stalled)}/{RUNS} setpoint streams stalled (sent, received): {stalled}"


if __name__ == "__main__":
    _peer(sys.argv[1], sys.argv[2], float(sys.argv[3]))
