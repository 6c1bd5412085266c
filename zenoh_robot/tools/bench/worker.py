"""One side of a benchmark cell, in its own process: ``python -m zenoh_robot.tools.bench.worker``.

``framework``: a Node publisher/subscription with the message type.
``raw``: zenoh-python declare_publisher/put of msgpack bytes of the same fields plus a
stamp, and a plain callback that unpacks them: the physical limit of this stack.
Prints ``READY`` when its session is up, then one JSON line with its figures.
"""
from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import threading
import time
from typing import Any

import msgpack
import zenoh

from zenoh_robot import HistoryPolicy, Node, QoSProfile, ReliabilityPolicy, SessionConfig
from zenoh_robot.message import type_support

from . import payloads

KEY = "bench/data"
MAX_AGES = 50_000


def _cpu() -> float:
    return time.process_time()   # all threads of this process, ns resolution (os.times ticks 10 ms)


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _config(args: argparse.Namespace) -> SessionConfig:
    endpoint = [f"tcp/127.0.0.1:{args.port}"]
    if args.role == "sub":
        return SessionConfig(listen=endpoint, multicast_scouting=False, shared_memory=False)
    return SessionConfig(listen=[], connect=endpoint, multicast_scouting=False, shared_memory=False)


def _qos(throughput: bool, express: bool = False) -> QoSProfile:
    # Throughput: reliable and KEEP_ALL (BLOCK), so nothing may be lost; latency: keep last 100.
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_ALL if throughput else HistoryPolicy.KEEP_LAST,
                      depth=0 if throughput else 100, express=express)


def run_sub(args: argparse.Namespace) -> dict[str, Any]:
    msg = payloads.make(args.payload)
    # Bounded, so a soak measures the framework's memory and not ours: the first MAX_AGES ages
    # give the percentiles, a counter and the first/last arrival give the rest.
    ages: list[float] = []
    received = 0
    first = last = 0.0
    cpu_first = math.nan
    done = threading.Event()
    rss: list[float] = []

    def record(stamp_ns: int) -> None:
        nonlocal received, first, last, cpu_first
        now = time.time_ns()
        if len(ages) < MAX_AGES:
            ages.append((now - stamp_ns) / 1e6)
        received += 1
        last = now / 1e9
        if received == 1:
            first = last
            cpu_first = _cpu()
        if received >= args.count:
            done.set()

    cfg = _config(args)
    cpu0 = 0.0
    if args.mode == "raw":
        session = zenoh.open(cfg.to_zenoh())
        try:
            def on_sample(sample: Any) -> None:
                values = msgpack.unpackb(sample.payload.to_bytes())
                type_support(type(msg)).decode(values[1])   # same decoding work as the framework's body
                record(values[0])
            sub = session.declare_subscriber(KEY, on_sample)
            print("READY", flush=True)
            cpu0 = _cpu()   # per-message CPU: count the flow, not imports and session set-up
            _wait(done, args, rss)
            sub.undeclare()
        finally:
            session.close()
    else:
        with Node("bench_sub", config=cfg) as node:
            node.create_subscription(type(msg), "/" + KEY, lambda m, info: record(info.source_stamp_ns),
                                     _qos(args.throughput), receive=args.receive)
            spinner = threading.Thread(target=node.spin, daemon=True)
            spinner.start()
            print("READY", flush=True)
            cpu0 = _cpu()
            _wait(done, args, rss)
            node.shutdown()
    # Per message: the flow after the first sample (samples 2..n). Before it, the publisher's discovery
    # (a framework node matches it on the graph once): reported apart, so that a 50-message cell does not
    # spread a one-off over its messages.
    end = _cpu()
    flow, setup = (end - cpu_first, cpu_first - cpu0) if received else (end - cpu0, math.nan)
    return {"received": received, "ages_ms": ages, "t_first": first or None, "t_last": last or None,
            "cpu_s": flow, "cpu_setup_s": setup, "rss_mb": rss,
            "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _wait(done: threading.Event, args: argparse.Namespace, rss: list[float]) -> None:
    deadline = time.monotonic() + args.timeout
    next_rss = time.monotonic()
    while not done.is_set() and time.monotonic() < deadline:
        if args.rss_every and time.monotonic() >= next_rss:
            rss.append(_rss_mb())
            next_rss += args.rss_every
        done.wait(0.05)
    if args.rss_every:
        rss.append(_rss_mb())


def run_pub(args: argparse.Namespace) -> dict[str, Any]:
    msg = payloads.make(args.payload)
    cfg = _config(args)
    period = 1.0 / args.rate if args.rate > 0 else 0.0
    if args.mode == "raw":
        session = zenoh.open(cfg.to_zenoh())
        try:
            cc = zenoh.CongestionControl.BLOCK if args.throughput else zenoh.CongestionControl.DROP
            pub = session.declare_publisher(KEY, reliability=zenoh.Reliability.RELIABLE, congestion_control=cc,
                                            express=args.express)
            time.sleep(args.settle)
            cpu0 = _cpu()

            encode = type_support(type(msg)).encode

            def send() -> None:
                # The encoding work a node does per publish (as the raw subscriber decodes per sample):
                # the ratio is then the framework's own cost, not the message's serialisation. Stamped
                # where a Node's publish stamps (publisher.py: after the field values, before packing).
                body = encode(msg)
                stamp = time.time_ns()
                pub.put(msgpack.packb((stamp, body), use_bin_type=True))
            sent, elapsed = _loop(send, args.count, period)
        finally:
            session.close()
    else:
        with Node("bench_pub", config=cfg) as node:
            node_pub = node.create_publisher(type(msg), "/" + KEY, _qos(args.throughput, args.express))
            time.sleep(args.settle)
            cpu0 = _cpu()
            sent, elapsed = _loop(lambda: node_pub.publish(msg), args.count, period)
            cpu = _cpu() - cpu0
            time.sleep(0.5)   # let the tail leave before the session closes
        return {"sent": sent, "elapsed_s": elapsed, "cpu_s": cpu}
    return {"sent": sent, "elapsed_s": elapsed, "cpu_s": _cpu() - cpu0}


def _loop(send: Any, count: int, period: float) -> tuple[int, float]:
    t0 = time.monotonic()
    for i in range(count):
        send()
        if period:
            delay = t0 + (i + 1) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    return count, time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("role", choices=("pub", "sub"))
    p.add_argument("mode", choices=("framework", "raw"))
    p.add_argument("payload", choices=payloads.PAYLOADS)
    p.add_argument("--rate", type=float, default=0.0, help="Hz; 0 = as fast as possible")
    p.add_argument("--count", type=int, required=True)
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--throughput", action="store_true")
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--settle", type=float, default=1.0)
    p.add_argument("--rss-every", type=float, default=0.0)
    p.add_argument("--receive", choices=("callback", "channel"), default=None,
                   help="the framework subscription's receive path (default: the library's)")
    p.add_argument("--express", action="store_true", help="publish with Zenoh's express (no batching), both modes")
    args = p.parse_args(argv)
    zenoh.init_log_from_env_or("error")
    out = run_sub(args) if args.role == "sub" else run_pub(args)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
