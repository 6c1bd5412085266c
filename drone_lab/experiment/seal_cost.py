"""What sealing costs, measured: plain vs sealed samples (``zenoh_robot.wire.sealed``), A/B alternating.

Two processes talk over Zenoh UDP multicast on ``lo`` (the resilient profile's transport): a GCS side
publishing ``DroneSetpoint`` and subscribing ``SensorCombined``, a drone side the reverse, each a real
``Node`` with either the plain envelope or ``sealed(ENVELOPE, Keyring(...))``. Per rep both wires run
once, in alternating order (A/B, then B/A), so load drift on a shared machine hits both alike. Per run
and side: process CPU over the window (all threads: Zenoh's, the executor, the repeater), samples
sent and received, CPU per sample, delivered %, age median and p99.

Scenarios (``--scenario``):

- ``streams``: the resilient profile's QoS (setpoint redundancy and repeats, sensor repeat 1) at
  ``--rate`` Hz each (default 50): what a GCS and a companion pay, whole process;
- ``per-sample``: both streams without copies (best effort, depth 5) at ``--rate`` Hz (use ~1000):
  one seal and one open per sample, the cost of the seal itself inside the stack.

    python -m drone_lab.experiment.seal_cost --scenario streams --reps 5 --out docs/results/seal_cost
"""
from __future__ import annotations

import argparse
import json
import os
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

MODULE = "drone_lab.experiment.seal_cost"
WIRES = ("plain", "sealed")
SCENARIOS = ("streams", "per-sample")
GCS_ID = "gcs1"
DRONE_ID = "uav1"
WARMUP_S = 4.0      # launch -> window: imports (cryptography on the sealed side) and discovery on the group


def _cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def endpoint(side: str, wire_name: str, keys_dir: str, group: str, scenario: str, rate: float, start_at: float,
             duration: float, out: Path) -> None:
    """One side: publish at ``rate`` from ``start_at`` (wall clock) for ``duration`` s, listen, write the figures."""
    from drone_contract.messages import DroneSetpoint
    from drone_contract.streams import stream_profile
    from zenoh_robot import Node, SessionConfig, qos
    from zenoh_robot.keyring import Keyring
    from zenoh_robot.msgs import Header, SensorCombined
    from zenoh_robot.wire import ENVELOPE, sealed

    name = GCS_ID if side == "gcs" else DRONE_ID
    wire = sealed(ENVELOPE, Keyring(keys_dir, name)) if wire_name == "sealed" else ENVELOPE
    if scenario == "streams":
        profile = stream_profile("resilient").qos
        sp_qos, se_qos = profile["setpoint"], profile["sensor"]
    else:
        sp_qos = se_qos = qos.SENSOR_DATA
    window = [start_at, start_at + duration]
    received: list[int] = []        # age of each sample received in the window, ns
    sent = 0

    def on_sample(msg: Any, info: Any) -> None:
        # By source stamp: a sample sent in the window counts wherever its arrival falls.
        if window[0] * 1e9 <= info.source_stamp_ns <= window[1] * 1e9:
            received.append(time.time_ns() - info.source_stamp_ns)

    config = SessionConfig.resilient("lo", group)
    with Node("gcs" if side == "gcs" else "companion", namespace=DRONE_ID, config=config, wire=wire) as node:
        if side == "gcs":
            node.create_subscription(SensorCombined, "sensor", on_sample, se_qos)
            pub: Any = node.create_publisher(DroneSetpoint, "setpoint", sp_qos)
        else:
            node.create_subscription(DroneSetpoint, "setpoint", on_sample, sp_qos)
            pub = node.create_publisher(SensorCombined, "sensor", se_qos)
        threading.Thread(target=node.spin, daemon=True).start()
        time.sleep(max(0.0, start_at - time.time()))
        cpu0, t0 = _cpu_s(), time.monotonic()
        period, next_t = 1.0 / rate, time.monotonic()
        end = t0 + max(0.0, window[1] - time.time())   # the same wall-clock window at both ends, late start or not
        while next_t < end:
            if side == "gcs":
                pub.publish(DroneSetpoint(client_id=GCS_ID, x=float(sent)))
            else:
                pub.publish(SensorCombined(header=Header.now()))
            sent += 1
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
        cpu1, t1 = _cpu_s(), time.monotonic()
        time.sleep(0.5)
        counters = wire.snapshot() if hasattr(wire, "snapshot") else {}
    ages = sorted(received)
    out.write_text(json.dumps({
        "side": side, "wire": wire_name, "cpu_s": cpu1 - cpu0, "elapsed_s": t1 - t0, "sent": sent,
        "received": len(ages), "age_p50_ms": ages[len(ages) // 2] / 1e6 if ages else None,
        "age_p99_ms": ages[min(len(ages) - 1, int(len(ages) * 0.99))] / 1e6 if ages else None,
        "seal_counters": counters}))


def run_one(wire: str, keys_dir: Path, scenario: str, rate: float, duration: float, workdir: Path) -> dict[str, Any]:
    """Both sides with ``wire``, on a group of their own; {side: figures}."""
    group = f"239.255.75.{random.randint(1, 250)}:{random.randint(20000, 60000)}"
    start_at = time.time() + WARMUP_S
    procs, outs = {}, {}
    for side in ("drone", "gcs"):
        outs[side] = workdir / f"{wire}-{side}.json"
        cmd = [sys.executable, "-m", MODULE, "endpoint", "--side", side, "--wire", wire, "--keys", str(keys_dir),
               "--group", group, "--scenario", scenario, "--rate", str(rate), "--start-at", repr(start_at),
               "--duration", str(duration), "--out", str(outs[side])]
        procs[side] = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=open(workdir / f"{wire}-{side}.log", "w"))
    for p in procs.values():
        p.wait(timeout=duration + WARMUP_S + 60)
    result: dict[str, Any] = {}
    for side, path in outs.items():
        r = json.loads(path.read_text())
        peer_sent = json.loads(outs["gcs" if side == "drone" else "drone"].read_text())["sent"]
        r["delivered_pct"] = 100.0 * r["received"] / peer_sent if peer_sent else None
        r["cpu_pct"] = 100.0 * r["cpu_s"] / r["elapsed_s"]
        r["cpu_us_per_sample"] = 1e6 * r["cpu_s"] / max(1, r["sent"] + r["received"])
        result[side] = r
    return result


def run(reps: int, scenario: str, rate: float, duration: float, out: Path) -> list[dict[str, Any]]:
    from zenoh_robot.tools import keys
    out.mkdir(parents=True, exist_ok=True)
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="zr-seal-cost-") as tmp:
        keys.make_link_keys(tmp, gcs={GCS_ID: [DRONE_ID]})
        keys_dir = Path(tmp) / keys.LINK_DIR
        for rep in range(reps):
            order = WIRES if rep % 2 == 0 else WIRES[::-1]
            for wire in order:
                workdir = out / "runs" / f"{scenario}-{rep}"
                workdir.mkdir(parents=True, exist_ok=True)
                r = {"rep": rep, "wire": wire, "scenario": scenario, "rate_hz": rate, "duration_s": duration,
                     "sides": run_one(wire, keys_dir, scenario, rate, duration, workdir)}
                runs.append(r)
                with (out / f"{scenario}.jsonl").open("a") as f:
                    f.write(json.dumps(r) + "\n")
                print(one_line(r), flush=True)
    return runs


def one_line(r: dict[str, Any]) -> str:
    return f"rep {r['rep']} {r['wire']:6s} " + " | ".join(
        f"{side}: cpu {s['cpu_pct']:5.2f} % {s['cpu_us_per_sample']:6.1f} us/sample, sent {s['sent']}, "
        f"delivered {s['delivered_pct']:5.1f} %, age p50 {s['age_p50_ms'] or 0:.2f} ms"
        for side, s in r["sides"].items())


def summary(runs: list[dict[str, Any]]) -> str:
    """Markdown: per side, median (min-max) of plain and sealed, and the sealed/plain ratio of medians."""
    def med(wire: str, side: str, field: str) -> tuple[float, float, float]:
        xs = [r["sides"][side][field] for r in runs if r["wire"] == wire and r["sides"][side][field] is not None]
        return (statistics.median(xs), min(xs), max(xs)) if xs else (float("nan"),) * 3

    rows = ["| side | figure | plain median (min-max) | sealed median (min-max) | sealed / plain |",
            "|---|---|---|---|---|"]
    for side in ("gcs", "drone"):
        for field, unit in (("cpu_us_per_sample", "µs"), ("cpu_pct", "%"), ("delivered_pct", "%"),
                            ("age_p50_ms", "ms"), ("age_p99_ms", "ms")):
            p, s = med("plain", side, field), med("sealed", side, field)
            rows.append(f"| {side} | {field} | {p[0]:.2f} ({p[1]:.2f}-{p[2]:.2f}) {unit} "
                        f"| {s[0]:.2f} ({s[1]:.2f}-{s[2]:.2f}) {unit} | {s[0] / p[0]:.3f} |")
    n = len({r["rep"] for r in runs})
    return "\n".join(rows) + f"\n\n{n} reps, A/B alternating, {runs[0]['rate_hz']:g} Hz per stream, " \
        f"{runs[0]['duration_s']:g} s windows, scenario {runs[0]['scenario']}, load avg {os.getloadavg()[0]:.2f}\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog=f"python -m {MODULE}", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd")
    e = sub.add_parser("endpoint", help="(internal) one side of a run")
    e.add_argument("--side", choices=("gcs", "drone"), required=True)
    e.add_argument("--wire", choices=WIRES, required=True)
    e.add_argument("--keys", required=True)
    e.add_argument("--group", required=True)
    e.add_argument("--scenario", choices=SCENARIOS, required=True)
    e.add_argument("--rate", type=float, required=True)
    e.add_argument("--start-at", type=float, required=True)
    e.add_argument("--duration", type=float, required=True)
    e.add_argument("--out", type=Path, required=True)
    p.add_argument("--scenario", choices=SCENARIOS, default="streams")
    p.add_argument("--reps", type=int, default=5)
    p.add_argument("--rate", type=float, default=50.0, help="Hz per stream")
    p.add_argument("--duration", type=float, default=10.0, help="measurement window per run, s")
    p.add_argument("--out", type=Path, default=Path("seal-cost"))
    args = p.parse_args(argv)
    if args.cmd == "endpoint":
        endpoint(args.side, args.wire, args.keys, args.group, args.scenario, args.rate, args.start_at, args.duration,
                 args.out)
        return 0
    runs = run(args.reps, args.scenario, args.rate, args.duration, args.out)
    table = summary(runs)
    (args.out / f"{args.scenario}.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
