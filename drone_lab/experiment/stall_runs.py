"""Many short resilient GCS <-> drone runs over multicast: does any stream stall? (issue #17)

Zenoh 1.10's UDP multicast transport once stopped sending for good now and then
(docs/zenoh-multicast-stall.md), more often under CPU load, so one run proves nothing.
This runs N short pairs, ``parallel`` at once (each pair in its own two namespaces
joined by a veth with no loss), optionally beside K busy-looping CPU hogs, and
reports for each: whether the setpoint or the FEC image stream stalled, and the
longest time the drone went without a new setpoint (first send -> last send, both
ends of the window included, so a stall shows as a long gap).

Each pair runs what the ``resilient`` profile runs on one session: a LossMonitor on
both nodes (20 Hz probes from its own thread), the GCS's setpoint copies following
the fed-back loss (``apply_repeat_plan``), and the drone's FEC images (a paced burst
of shares per frame). ``ZR_STALL_EXPRESS=1`` forces express on the GCS's setpoints
(the old setting, past the library's workaround) to see the stall come back.

``python -m drone_lab.experiment.stall_runs --runs 50 [--hogs 2] [--parallel 8]``
(root: it builds network namespaces). One pair is one run. Inside a pair the helper
processes run ``--peer pub|sub IFACE SECONDS``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass
from typing import IO, Any, TextIO

SECONDS = 4.0
RATE_HZ = 10.0
IMAGE_HZ = 10.0
PARALLEL = 8          # pairs at once: the stall needs load, and the pairs are part of it
OFFBOARD_GAP_MS = 500.0
HELPER_TIMEOUT_S = 120.0


def _wait_line(word: str) -> None:
    for line in sys.stdin:
        if line.strip() == word:
            return


def _monitor_summary(monitor: Any) -> dict[str, Any]:
    return {"probes_sent": monitor.probes_sent, "probes_received": monitor.probes_received,
            "peers": len(monitor.incoming_loss())}


def peer(role: str, iface: str, seconds: float) -> None:
    """pub: the GCS (setpoints out, images in); sub: the drone (setpoints in, images out).

    Protocol on stdin/stdout: READY; "go" starts this side's stream; one JSON line when it has
    sent everything; "stop" ends listening; one JSON line with what it received. Times are
    CLOCK_MONOTONIC, one clock for every namespace of the machine, so the parent can compare them."""
    import numpy as np

    from drone_contract.streams import stream_profile
    from zenoh_robot import Node
    from zenoh_robot.image.fec import FecImagePublisher, FecImageSubscription
    from zenoh_robot.loss_feedback import LossMonitor, apply_repeat_plan
    from zenoh_robot.msgs import Header, Setpoint
    from zenoh_robot.qos_mapping import declare_publisher
    from zenoh_robot.session_config import SessionConfig

    profile = stream_profile("resilient")
    assert profile.loss_feedback and profile.image_mode == "fec"
    qos = profile.qos["setpoint"]
    with Node(f"stall_{role}", config=SessionConfig.resilient(iface)) as node:
        monitor = LossMonitor(node, "gcs" if role == "pub" else "drone")
        node.add_on_close(monitor.close)
        spinner = threading.Thread(target=node.spin, daemon=True)
        spinner.start()
        if role == "pub":
            pub = node.create_publisher(Setpoint, "stall/setpoint", qos)
            if os.environ.get("ZR_STALL_EXPRESS") == "1":   # the old setting, to see the stall
                pub._zpub = declare_publisher(node.session, pub.key, qos.replace(express=True))
            monitor.adapt(lambda loss: apply_repeat_plan(pub, loss))
            frames: set[int] = set()
            FecImageSubscription(node, "stall/image", lambda img, info: frames.add(info.frame))
            print("READY", flush=True)
            _wait_line("go")
            n = int(seconds * RATE_HZ)
            t0 = time.monotonic()
            first_ns = time.monotonic_ns()
            for i in range(n):
                pub.publish(Setpoint(Header.now(seq=i), x=float(i)))
                time.sleep(max(0.0, t0 + (i + 1) / RATE_HZ - time.monotonic()))
            print(json.dumps({"sent": n, "first_ns": first_ns, "end_ns": time.monotonic_ns(),
                              "express_on_wire": pub.express_on_wire, "repeats": pub.repeats}), flush=True)
            _wait_line("stop")
            print(json.dumps({"frames": len(frames), "last_frame": max(frames, default=-1),
                              **_monitor_summary(monitor)}), flush=True)
        else:
            seqs: set[int] = set()
            arrivals: list[int] = []     # bounded by the setpoints sent (RATE_HZ x seconds)

            def on_setpoint(m: Setpoint) -> None:
                if m.header.seq not in seqs:
                    seqs.add(m.header.seq)
                    arrivals.append(time.monotonic_ns())
            node.create_subscription(Setpoint, "stall/setpoint", on_setpoint, qos.replace(depth=100))
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
                time.sleep(max(0.0, t0 + images.frames / IMAGE_HZ - time.monotonic()))
            print(json.dumps({"frames_sent": n, "shares_sent": images.shares_sent, "k": images.last_k,
                              "n": images.last_n}), flush=True)
            _wait_line("stop")
            print(json.dumps({"unique": len(seqs), "last": max(seqs, default=-1), "arrivals_ns": arrivals,
                              **_monitor_summary(monitor)}), flush=True)
        node.shutdown()


@dataclass
class PairResult:
    """One run: what the GCS sent and the drone got, and the other way for images."""
    sent: int
    unique: int
    last: int
    longest_gap_ms: float        # first send -> each new setpoint -> last send
    gaps_over_500ms: int
    frames_sent: int
    frames: int
    last_frame: int
    express_on_wire: bool
    repeats: int
    peers_seen: int               # the fewer of the two nodes' peer counts (from their probes)
    error: str = ""

    @property
    def setpoint_stalled(self) -> bool:
        return bool(self.error) or self.unique < 0.9 * self.sent or self.last < self.sent - 3

    @property
    def image_stalled(self) -> bool:
        return bool(self.error) or self.frames < 0.8 * self.frames_sent or self.last_frame < self.frames_sent - 4

    @property
    def stalled(self) -> bool:
        return self.setpoint_stalled or self.image_stalled


def setpoint_gaps_ms(first_ns: int, end_ns: int, arrivals_ns: list[int]) -> list[float]:
    """Gaps the drone saw between new setpoints, the window's edges included: nothing for the
    whole window is one gap of its length, a stream that stopped ends in a gap up to end_ns."""
    points = [first_ns, *sorted(t for t in arrivals_ns if first_ns <= t <= end_ns), end_ns]
    return [(b - a) / 1e6 for a, b in zip(points, points[1:], strict=False)]


def _read_json_line(stream: IO[str]) -> dict[str, Any]:
    """The next JSON line a helper prints (Zenoh 1.10 logs its own lines to stdout too)."""
    for line in stream:
        if line.startswith("{"):
            return dict(json.loads(line))
    raise RuntimeError("helper ended without its JSON line")


def wait_ready(proc: subprocess.Popen[str], max_lines: int = 50, word: str = "READY") -> bool:
    """Read a helper process's stdout up to its ``word`` line (READY). Zenoh 1.10 logs its own errors to
    stdout (e.g. a transient "Unknown wire expr" while sessions meet): those lines are not the protocol."""
    assert proc.stdout is not None
    for _ in range(max_lines):
        line = proc.stdout.readline()
        if not line:
            return False
        if line.strip() == word:
            return True
    return False


def reap(*procs: subprocess.Popen[str], timeout: float = 10.0) -> None:
    """Wait for each helper to end, killing one that does not within ``timeout``."""
    for proc in procs:
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout)


def _last_json(out: str) -> dict[str, Any]:
    for line in reversed(out.strip().splitlines()):
        if line.startswith("{"):
            return dict(json.loads(line))
    raise RuntimeError(f"no JSON summary in: {out[-500:]!r}")


@contextmanager
def cpu_hogs(count: int) -> Iterator[None]:
    """Busy loops at nice 5, as in the outside harness that first saw the stall."""
    hogs = [subprocess.Popen(["nice", "-n", "5", sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def run_pairs(pairs: int, seconds: float = SECONDS) -> list[PairResult]:
    """``pairs`` GCS <-> drone pairs at once, each over its own veth; one result per pair."""
    from .netns import LossyLink

    cmd = [sys.executable, "-m", "drone_lab.experiment.stall_runs", "--peer"]
    with ExitStack() as stack:
        links = [stack.enter_context(LossyLink(loss_pct=0)) for _ in range(pairs)]
        drones: list[subprocess.Popen[str]] = []
        gcss: list[subprocess.Popen[str]] = []
        for link in links:
            for side, role, procs in (("drone", "sub", drones), ("gcs", "pub", gcss)):
                p = subprocess.Popen(link.exec_in(side) + cmd + [role, link.dev(side), str(seconds)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
                stack.callback(p.wait)
                stack.callback(p.kill)
                procs.append(p)
        for p in drones + gcss:
            if not wait_ready(p):
                raise RuntimeError("a helper ended before READY (see its output above)")
        time.sleep(1.0)       # a few Join rounds (every 250 ms): the peers know each other

        def tell(word: str) -> None:
            for p in drones + gcss:
                assert p.stdin is not None
                p.stdin.write(word + "\n")
                p.stdin.flush()
        tell("go")
        sent_sp = [_read_json_line(p.stdout) for p in gcss if p.stdout is not None]
        sent_img = [_read_json_line(p.stdout) for p in drones if p.stdout is not None]
        time.sleep(0.5)       # the last copies and shares land
        tell("stop")
        results = []
        for drone, gcs, sp, img in zip(drones, gcss, sent_sp, sent_img, strict=True):
            d_out, _ = drone.communicate(timeout=HELPER_TIMEOUT_S)
            g_out, _ = gcs.communicate(timeout=HELPER_TIMEOUT_S)
            error = "" if drone.returncode == 0 and gcs.returncode == 0 else \
                f"exit codes drone {drone.returncode} gcs {gcs.returncode}: {d_out[-300:]!r} {g_out[-300:]!r}"
            try:
                got_sp, got_img = _last_json(d_out), _last_json(g_out)
            except RuntimeError as exc:
                got_sp, got_img, error = {}, {}, error or str(exc)
            gaps = setpoint_gaps_ms(sp["first_ns"], sp["end_ns"], got_sp.get("arrivals_ns", []))
            results.append(PairResult(
                sent=sp["sent"], unique=got_sp.get("unique", 0), last=got_sp.get("last", -1),
                longest_gap_ms=max(gaps), gaps_over_500ms=sum(g > OFFBOARD_GAP_MS for g in gaps),
                frames_sent=img["frames_sent"], frames=got_img.get("frames", 0),
                last_frame=got_img.get("last_frame", -1), express_on_wire=sp["express_on_wire"],
                repeats=sp["repeats"], peers_seen=min(got_sp.get("peers", 0), got_img.get("peers", 0)), error=error))
    return results


def run_many(runs: int, parallel: int = PARALLEL, seconds: float = SECONDS,
             out: TextIO = sys.stdout) -> list[PairResult]:
    """``runs`` pairs in consecutive batches of ``parallel``, one line per run as it ends."""
    results: list[PairResult] = []
    while len(results) < runs:
        batch = run_pairs(min(parallel, runs - len(results)), seconds)
        for r in batch:
            results.append(r)
            verdict = "STALLED" if r.stalled else "ok"
            out.write(f"run {len(results):3d}: {verdict:7s} setpoints {r.unique}/{r.sent} longest gap "
                      f"{r.longest_gap_ms:6.0f} ms | FEC frames {r.frames}/{r.frames_sent}"
                      f"{' | ' + r.error if r.error else ''}\n")
        out.flush()
    return results


def summary(results: list[PairResult]) -> dict[str, Any]:
    gaps = sorted(r.longest_gap_ms for r in results)
    return {"runs": len(results), "stalled": sum(r.stalled for r in results),
            "setpoint_stalled": sum(r.setpoint_stalled for r in results),
            "image_stalled": sum(r.image_stalled for r in results),
            "runs_with_gap_over_500ms": sum(r.gaps_over_500ms > 0 for r in results),
            "worst_gap_ms": gaps[-1] if gaps else None, "median_longest_gap_ms": gaps[len(gaps) // 2] if gaps else None,
            "express_on_wire": sum(r.express_on_wire for r in results)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m drone_lab.experiment.stall_runs", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=50, help="pairs in all (one pair = one run)")
    ap.add_argument("--parallel", type=int, default=PARALLEL, help="pairs at once")
    ap.add_argument("--seconds", type=float, default=SECONDS, help="streaming time of each run")
    ap.add_argument("--hogs", type=int, default=0, help="busy-looping CPU hogs (nice 5) during the runs")
    ap.add_argument("--json", type=str, default="", help="also write every run and the summary here")
    ap.add_argument("--peer", nargs=3, metavar=("ROLE", "IFACE", "SECONDS"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.peer:
        peer(args.peer[0], args.peer[1], float(args.peer[2]))
        return 0
    from .netns import unavailable_reason
    reason = unavailable_reason()
    if reason:
        print(f"cannot run: {reason}", file=sys.stderr)
        return 2
    t0 = time.monotonic()
    with cpu_hogs(args.hogs):
        results = run_many(args.runs, args.parallel, args.seconds)
    s = {**summary(results), "hogs": args.hogs, "parallel": args.parallel, "seconds": args.seconds,
         "wall_s": round(time.monotonic() - t0, 1)}
    print(f"runs {s['runs']}, stalled {s['stalled']} (setpoints {s['setpoint_stalled']}, images "
          f"{s['image_stalled']}), runs with a setpoint gap > 500 ms {s['runs_with_gap_over_500ms']}, "
          f"worst gap {s['worst_gap_ms']:.0f} ms, median longest gap {s['median_longest_gap_ms']:.0f} ms, "
          f"{args.hogs} hogs, {s['wall_s']} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"summary": s, "runs": [asdict(r) for r in results]}, f, indent=1)
    return 1 if s["stalled"] else 0


if __name__ == "__main__":
    sys.exit(main())
