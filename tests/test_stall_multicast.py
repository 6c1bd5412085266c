"""The resilient streams must never stall on the multicast transport (docs/zenoh-multicast-stall.md).

Zenoh 1.10's UDP multicast transport stops sending for good when express samples go out in
quick succession (a setpoint and its 3 ms repeats), more often when other processes load the
CPU. The stall hit a run now and then, so one run proves nothing: this test runs many short
GCS <-> drone pairs at once (each pair in its own namespaces, joined by a veth with no loss),
under two busy-looping CPU hogs, and asserts that every stream delivered to the end.

Each pair runs what the ``resilient`` profile runs on one session, as the apps start it: a
LinkMonitor on both nodes (a 20 Hz probe put from its own thread, outside the executor), the
GCS's setpoint copies following the fed-back loss (``apply_repeat_plan``: the repeater thread
puts copies 3 ms+ apart), and the drone sending FEC images (a paced burst of shares per frame,
``CongestionControl.BLOCK``) adapted by the same monitor. So three threads put concurrently on
each multicast session. With ``ZR_STALL_EXPRESS=1`` the GCS's setpoints go out with express
(the old setting, forced past the library's workaround): then the test fails in most runs.

Run as a script it is one side of a pair: ``python test_stall_multicast.py pub|sub IFACE SECONDS``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest
from conftest import last_json, wait_ready

ROOT = Path(__file__).resolve().parents[1]
RUNS = 8            # at once: the stall needs load, and the runs are part of it
SECONDS = 4.0
RATE_HZ = 10.0
IMAGE_HZ = 10.0


def _wait_line(word: str) -> None:
    for line in sys.stdin:
        if line.strip() == word:
            return


def _monitor_summary(monitor: Any) -> dict[str, Any]:
    return {"probes_sent": monitor.probes_sent, "probes_received": monitor.probes_received,
            "peers": len(monitor.incoming_loss())}


def _peer(role: str, iface: str, seconds: float) -> None:
    """pub: the GCS (setpoints out, images in); sub: the drone (setpoints in, images out).

    Protocol on stdin/stdout: READY; "go" starts this side's stream; one JSON line when it has
    sent everything; "stop" ends listening; one JSON line with what it received."""
    import numpy as np

    from zenoh_robot import Node
    from zenoh_robot._wire.feedback import LinkMonitor, apply_repeat_plan
    from zenoh_robot.image_fec import FecImagePublisher, FecImageSubscription
    from zenoh_robot.msgs import Header, Setpoint
    from zenoh_robot.qos_mapping import declare_publisher
    from zenoh_robot.session_config import SessionConfig
    from zenoh_robot.tools.stream_profiles import stream_profile

    profile = stream_profile("resilient")
    assert profile.loss_feedback and profile.image_mode == "fec"
    qos = profile.qos["setpoint"]
    with Node(f"stall_{role}", config=SessionConfig.resilient(iface)) as node:
        monitor = LinkMonitor(node)
        node.add_on_close(monitor.close)
        spinner = threading.Thread(target=node.spin, daemon=True)
        spinner.start()
        if role == "pub":
            pub = node.create_publisher(Setpoint, "stall/setpoint", qos)
            if os.environ.get("ZR_STALL_EXPRESS") == "1":   # the old setting, to see this test fail
                pub._zpub = declare_publisher(node.session, pub.key, qos.replace(express=True))
            monitor.adapt(lambda loss: apply_repeat_plan(pub, loss))
            frames: set[int] = set()
            FecImageSubscription(node, "stall/image", lambda img, info: frames.add(info.frame))
            print("READY", flush=True)
            _wait_line("go")
            n = int(seconds * RATE_HZ)
            t0 = time.monotonic()
            for i in range(n):
                pub.publish(Setpoint(Header.now(seq=i), x=float(i)))
                time.sleep(max(0.0, t0 + (i + 1) / RATE_HZ - time.monotonic()))
            print(json.dumps({"sent": n, "express_on_wire": pub.express_on_wire, "repeats": pub.repeats}), flush=True)
            _wait_line("stop")
            print(json.dumps({"frames": len(frames), "last_frame": max(frames, default=-1),
                              **_monitor_summary(monitor)}), flush=True)
        else:
            seqs: set[int] = set()
            node.create_subscription(Setpoint, "stall/setpoint", lambda m: seqs.add(m.header.seq),
                                     qos.replace(depth=100))
            images = FecImagePublisher(node, "stall/image", profile.qos["image"], quality=profile.jpeg_quality)
            monitor.adapt(images.set_loss)
            # Noise: a JPEG of several shares (a burst per frame, as the camera's), not one datagram.
            frame = np.random.default_rng(1).integers(0, 255, (96, 128, 3), dtype=np.uint8)
            print("READY", flush=True)
            _wait_line("go")
            n = int(seconds * IMAGE_HZ)
            t0 = time.monotonic()
            for _ in range(n):
                images.publish(frame)
                time.sleep(max(0.0, t0 + (images.frames) / IMAGE_HZ - time.monotonic()))
            print(json.dumps({"frames_sent": n, "shares_sent": images.shares_sent, "k": images.last_k,
                              "n": images.last_n}), flush=True)
            _wait_line("stop")
            print(json.dumps({"unique": len(seqs), "last": max(seqs, default=-1), **_monitor_summary(monitor)}),
                  flush=True)
        node.shutdown()


def _read_json_line(proc: subprocess.Popen) -> dict[str, Any]:
    """The next JSON line a helper prints (skipping Zenoh's own log lines)."""
    assert proc.stdout is not None
    for line in proc.stdout:
        if line.startswith("{"):
            return json.loads(line)
    raise AssertionError("helper ended without its JSON line")


@pytest.fixture
def cpu_hogs():
    """Two busy loops at nice 5, as in the outside harness that first saw the stall."""
    hogs = [subprocess.Popen(["nice", "-n", "5", sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    yield
    for h in hogs:
        h.kill()
        h.wait()


@pytest.mark.netns
def test_resilient_streams_with_loss_feedback_never_stall_on_multicast_under_cpu_load(cpu_hogs: None) -> None:
    pytest.importorskip("zfec", reason="FEC images need the [image] extra")
    from conftest import skip_unless_required

    from zenoh_robot.tools.experiment.netns import LossyLink, unavailable_reason

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"multicast stall test: network namespaces are unavailable: {reason}")
    me = str(Path(__file__).resolve())
    with ExitStack() as stack:
        links = [stack.enter_context(LossyLink(loss_pct=0)) for _ in range(RUNS)]
        drones, gcss = [], []
        for link in links:
            for side, role, procs in (("drone", "sub", drones), ("gcs", "pub", gcss)):
                p = subprocess.Popen(link.exec_in(side) + [sys.executable, me, role, link.dev(side), str(SECONDS)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
                stack.callback(p.kill)
                procs.append(p)
        for p in drones + gcss:
            assert p.stdout is not None and wait_ready(p)
        time.sleep(1.0)       # a few Join rounds (every 250 ms): the peers know each other

        def tell(word: str) -> None:
            for p in drones + gcss:
                assert p.stdin is not None
                p.stdin.write(word + "\n")
                p.stdin.flush()
        tell("go")
        sent_sp = [_read_json_line(p) for p in gcss]
        sent_img = [_read_json_line(p) for p in drones]
        time.sleep(0.5)       # the last copies and shares land
        tell("stop")
        got_sp, got_img = [], []
        for drone, gcs in zip(drones, gcss, strict=True):
            d_out, _ = drone.communicate(timeout=30)
            g_out, _ = gcs.communicate(timeout=30)
            assert drone.returncode == 0 and gcs.returncode == 0, (d_out[-2000:], g_out[-2000:])
            got_sp.append(last_json(d_out))
            got_img.append(last_json(g_out))
    if os.environ.get("ZR_STALL_EXPRESS") != "1":
        assert all(not p["express_on_wire"] for p in sent_sp), "express reached a multicast session"
    stalled = [(p["sent"], s) for p, s in zip(sent_sp, got_sp, strict=True)
               if s["unique"] < 0.9 * p["sent"] or s["last"] < p["sent"] - 3]
    assert not stalled, f"{len(stalled)}/{RUNS} setpoint streams stalled (sent, received): {stalled}"
    blind = [(d["frames_sent"], g) for d, g in zip(sent_img, got_img, strict=True)
             if g["frames"] < 0.8 * d["frames_sent"] or g["last_frame"] < d["frames_sent"] - 4]
    assert not blind, f"{len(blind)}/{RUNS} FEC image streams stalled (sent, received): {blind}"
    # The feedback was really on: every node heard its peer's probes, and the GCS sized its copies
    # from them (64 until the first report, and at a stalled peer's "100 %"; 16 at no loss).
    assert all(r["peers"] >= 1 for r in got_sp + got_img), (got_sp, got_img)
    assert all(p["repeats"] < 64 for p in sent_sp), sent_sp


if __name__ == "__main__":
    _peer(sys.argv[1], sys.argv[2], float(sys.argv[3]))
