"""``zenoh-robot demo``: the whole system on localhost, flying a square, with live statistics.

Three processes, as on a drone: the PX4 simulator, the companion (MAVLink <-> Zenoh)
and the GCS (mission + dashboard in this terminal). At the end, one summary joins
both ends' records: delivered %, age and period per stream, and how far the vehicle
strayed from the path.
"""
from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from rich.console import Console
from rich.table import Table

from ..stream_metrics import StreamRecorder, analyse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run simulator + companion + GCS on localhost and fly a square")
    p.add_argument("--duration", type=float, default=60.0, help="seconds of pattern flight (default 60)")
    p.add_argument("--pattern", default="square", choices=("square", "circle", "line", "hover"))
    p.add_argument("--profile", default="resilient", help="stream profile (default resilient)")
    p.add_argument("--drone", default="uav1")
    p.set_defaults(func=run)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen, name: str, console: Console) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            console.print(f"demo: {name} did not stop in 10 s; killing it")
            proc.kill()
            proc.wait()


def run(args: argparse.Namespace) -> int:
    console = Console()
    work = Path(tempfile.mkdtemp(prefix="zenoh-robot-demo-"))
    port = _free_udp_port()
    py = sys.executable
    logs = {name: open(work / f"{name}.log", "w") for name in ("sim", "companion")}
    console.print(f"demo: simulator, companion and GCS on localhost; logs in {work}")
    sim = subprocess.Popen([py, "-m", "px4_link.sim", "--port", "0", "--target-port", str(port)],
                           stdout=logs["sim"], stderr=subprocess.STDOUT)
    companion = subprocess.Popen([py, "-m", "companion", "--id", args.drone, "--px4", f"udpin:127.0.0.1:{port}",
                                  "--profile", args.profile, "--record", str(work / "companion.json")],
                                 stdout=logs["companion"], stderr=subprocess.STDOUT)
    gcs_cmd = [py, "-m", "gcs", "--drones", args.drone, "--mission", "--duration", str(args.duration),
               "--pattern", args.pattern, "--profile", args.profile, "--record", str(work / "gcs.json")]
    gcs = subprocess.Popen(gcs_cmd)
    rc = 1
    try:
        rc = gcs.wait()
    except KeyboardInterrupt:
        console.print("demo: interrupted; stopping")
        _stop(gcs, "gcs", console)
    finally:
        _stop(companion, "companion", console)
        _stop(sim, "simulator", console)
        for f in logs.values():
            f.close()
    for name, proc in (("simulator", sim), ("companion", companion)):
        if proc.returncode not in (0, -signal.SIGINT, 130):
            console.print(f"demo: {name} exited with {proc.returncode}; see {work / (name[:3] if name == 'simulator' else name)}.log")
    print_summary(console, work, args.drone)
    return rc


def print_summary(console: Console, work: Path, drone: str) -> None:
    try:
        gcs = json.loads((work / "gcs.json").read_text())["drones"][drone]
        comp = json.loads((work / "companion.json").read_text())
    except (OSError, ValueError, KeyError) as exc:
        console.print(f"demo: no summary ({exc})")
        return
    sent, recv = gcs["logs"]["sent"], gcs["logs"]["received"]
    pairs = {"setpoint ->": (comp["logs"]["received"]["setpoint"], sent["setpoint"]),
             "sensor <-": (recv["sensor"], comp["logs"]["sent"]["sensor"]),
             "state <-": (recv["state"], comp["logs"]["sent"]["state"]),
             "image <-": (recv["image"], comp["logs"]["sent"]["image"])}
    t = Table(title="demo summary (-> GCS to drone, <- drone to GCS)")
    for col in ("stream", "sent", "delivered %", "age avg ms", "age p99 ms", "period avg ms", "period max ms"):
        t.add_column(col, justify="right" if col != "stream" else "left")
    for name, (r, s) in pairs.items():
        # Over the time both ends were up: from the first to the last sample that arrived.
        stamps = r["stamp_ns"] or [0]
        a = analyse(StreamRecorder.from_dict(r), StreamRecorder.from_dict(s), min(stamps), max(stamps))
        t.add_row(name, str(a.sent), f"{a.delivered_pct:.1f}", f"{a.age_avg_ms:.1f}", f"{a.age_p99_ms:.1f}",
                  f"{a.period_avg_ms:.1f}", f"{a.period_max_ms:.1f}")
    console.print(t)
    console.print(f"largest distance from the setpoint path: {gcs['max_path_error_m']:.2f} m; "
                  f"frames shown {gcs['frames']} ({gcs['frames_complete']} whole); "
                  f"setpoints rejected by the companion: {comp['setpoints_rejected']}; "
                  f"final mode {comp['final_mode']}")
