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

Before/after a change: run the same command in a clone of the old tree and in this one, alternating,
into two folders, then ``compare``: per side, the sealed/plain ratio of CPU per sample (medians, and
the median of each rep's own pair), and the AEAD calls per sample the seal counters show::

    python -m drone_lab.experiment.seal_cost compare --before DIR --after DIR [--scenario streams]

Whole-process CPU moves by +-20 % run to run on a shared machine, far more than a seal costs. ``stack``
measures what the seal adds to the stack itself, in one process without Zenoh, as the wire sees a
sample sent with ``copies`` copies: plain (pack, then unpack each copy), sealed per copy (a seal and an
open per copy: the scheme before seal-once) and sealed once (one seal, one open, the other copies
refused as duplicates); process CPU per sample, the best of ``--rounds``::

    python -m drone_lab.experiment.seal_cost stack --copies 1,2,4,16 --samples 20000
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


def _pairs(runs: list[dict[str, Any]]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """(plain, sealed) of each rep: the jsonl holds a rep's two runs next to each other."""
    out = []
    for a, b in zip(runs[::2], runs[1::2], strict=False):   # an odd last run (cut short) has no pair
        if a["rep"] == b["rep"] and {a["wire"], b["wire"]} == set(WIRES):
            out.append((a, b) if a["wire"] == "plain" else (b, a))
    return out


def aead_per_sample(run: dict[str, Any], side: str) -> float | None:
    """AEAD calls (seals + opens) per sample sent or received, from a sealed run's counters."""
    s = run["sides"][side]
    counters = s.get("seal_counters") or {}
    samples = s["sent"] + s["received"]
    return (counters.get("sealed", 0) + counters.get("opened", 0)) / samples if counters and samples else None


def compare(before: Path, after: Path, scenario: str) -> str:
    """Markdown: per tree and side, CPU per sample plain vs sealed, the ratios, AEAD calls per sample."""
    rows = ["| tree | side | runs | plain µs/sample, median (min-max) | sealed µs/sample, median (min-max) "
            "| sealed / plain (medians) | sealed / plain (per rep, median) | AEAD calls per sample | duplicates "
            "refused per received sample |", "|---|---|---|---|---|---|---|---|---|"]
    for label, folder in (("before", before), ("after", after)):
        runs = [json.loads(line) for line in (folder / f"{scenario}.jsonl").read_text().splitlines() if line]
        pairs = _pairs(runs)
        for side in ("gcs", "drone"):
            plain = [p["sides"][side]["cpu_us_per_sample"] for p, _ in pairs]
            sealed = [s["sides"][side]["cpu_us_per_sample"] for _, s in pairs]
            ratios = [b / a for a, b in zip(plain, sealed, strict=True)]
            calls = [c for _, s in pairs if (c := aead_per_sample(s, side)) is not None]
            dups = [s["sides"][side]["seal_counters"].get("duplicate", 0) / max(1, s["sides"][side]["received"])
                    for _, s in pairs]
            mp, ms = statistics.median(plain), statistics.median(sealed)
            rows.append(f"| {label} | {side} | {len(pairs)} | {mp:.1f} ({min(plain):.1f}-{max(plain):.1f}) "
                        f"| {ms:.1f} ({min(sealed):.1f}-{max(sealed):.1f}) | {ms / mp:.3f} "
                        f"| {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}) "
                        f"| {statistics.median(calls):.2f} | {statistics.median(dups):.2f} |")
    return "\n".join(rows) + "\n"


def stack(copies: int, samples: int, rounds: int, keys_dir: Path) -> dict[str, float]:
    """µs of process CPU per sample (publisher + subscriber side) of each scheme for ``copies`` copies."""
    from drone_contract.messages import DroneSetpoint
    from zenoh_robot.keyring import Keyring
    from zenoh_robot.message import type_support
    from zenoh_robot.wire import ENVELOPE, DuplicateSample, sealed

    ts = type_support(DroneSetpoint)
    body = ts.encode(DroneSetpoint(client_id=GCS_ID, x=1.0, y=2.0, z=-3.0))
    key = f"{DRONE_ID}/setpoint"
    pack = ENVELOPE.encoder(ts, 7).pack
    unpack = ENVELOPE.decoder(ts)
    gcs_wire, drone_wire = sealed(ENVELOPE, Keyring(keys_dir, GCS_ID)), sealed(ENVELOPE, Keyring(keys_dir, DRONE_ID))
    if hasattr(drone_wire, "own"):    # the GCS hears the drone once, as before it flies it (wire/freshness.py)
        from zenoh_robot.msgs import SensorCombined
        sensor, sensor_key = type_support(SensorCombined), f"{DRONE_ID}/sensor"
        heard = drone_wire.sealer(sensor_key)(ENVELOPE.encoder(sensor, 8).pack(1, 1, sensor.encode(SensorCombined())))
        gcs_wire.keyed_decoder(sensor, sensor_key)(heard, None)

    def plain(n: int) -> None:
        for seq in range(1, n + 1):
            payload = pack(seq, seq, body)
            for _ in range(copies):
                unpack(payload, None)

    def per_copy(n: int) -> None:
        seal, opened = gcs_wire.sealer(key), drone_wire.keyed_decoder(ts, key)
        for seq in range(1, n + 1):
            payload = pack(seq, seq, body)
            for _ in range(copies):
                opened(seal(payload), None)

    def once(n: int) -> None:
        seal, opened = gcs_wire.sealer(key, repeated=True), drone_wire.keyed_decoder(ts, key)
        for seq in range(1, n + 1):
            sealed_payload = seal(pack(seq, seq, body))
            opened(sealed_payload, None)
            for _ in range(copies - 1):
                try:
                    opened(sealed_payload, None)
                except DuplicateSample:
                    pass

    out: dict[str, float] = {}
    for name, fn in (("plain", plain), ("sealed_per_copy", per_copy), ("sealed_once", once)):
        fn(1000)    # warm: imports, subkeys, caches
        best = float("inf")
        for _ in range(rounds):
            t0 = time.process_time_ns()
            fn(samples)
            best = min(best, (time.process_time_ns() - t0) / samples / 1e3)
        out[name] = best
    return out


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
    k = sub.add_parser("stack", help="what the seal adds per sample in the stack (one process, no Zenoh)")
    k.add_argument("--copies", default="1,2,4,16", help="copies per sample, comma separated")
    k.add_argument("--samples", type=int, default=20000)
    k.add_argument("--rounds", type=int, default=5)
    k.add_argument("--out", type=Path, default=None, help="also write the rows here as JSON")
    c = sub.add_parser("compare", help="before/after tables from two output folders")
    c.add_argument("--before", type=Path, required=True)
    c.add_argument("--after", type=Path, required=True)
    c.add_argument("--scenario", choices=SCENARIOS, default="streams")
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
    if args.cmd == "stack":
        from zenoh_robot.tools import keys
        rows = []
        with tempfile.TemporaryDirectory(prefix="zr-seal-stack-") as tmp:
            keys.make_link_keys(tmp, gcs={GCS_ID: [DRONE_ID]})
            for n in (int(c) for c in args.copies.split(",")):
                r = stack(n, args.samples, args.rounds, Path(tmp) / keys.LINK_DIR)
                rows.append({"copies": n, **r})
                print(f"copies {n:3d}: plain {r['plain']:6.2f} µs, sealed per copy {r['sealed_per_copy']:6.2f} µs "
                      f"(+{r['sealed_per_copy'] - r['plain']:.2f}), sealed once {r['sealed_once']:6.2f} µs "
                      f"(+{r['sealed_once'] - r['plain']:.2f}) a sample", flush=True)
        if args.out is not None:
            args.out.write_text(json.dumps({"samples": args.samples, "rounds": args.rounds, "rows": rows,
                                            "load_avg": os.getloadavg()[0]}, indent=1) + "\n")
        return 0
    if args.cmd == "compare":
        print(compare(args.before, args.after, args.scenario), end="")
        return 0
    runs = run(args.reps, args.scenario, args.rate, args.duration, args.out)
    table = summary(runs)
    (args.out / f"{args.scenario}.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
