"""``zenoh-robot bench --ros2``: the ROS 2 wire beside the envelope and raw zenoh-python.

Two parts. **Codec**: per ROS 2 type, in this process, the time to turn a message into its wire
bytes and back: CDR (the ROS 2 wire: TypeSupport body -> rosbags' serializer, and back with field
validation) beside the envelope's msgpack body of the same class. **End to end**: two processes
over TCP loopback, the same ROS 2 class (geometry_msgs/msg/PoseStamped by default) published by a
Node on the ROS 2 wire, by a Node on the envelope, and as raw zenoh-python puts of its CDR bytes
with a stamp (the physical limit): p50/p99 age at a fixed rate, and messages per second as fast
as reliable KEEP_ALL allows. Run alone: ``python -m zenoh_robot.tools.bench.ros2 [--quick]``.
"""
from __future__ import annotations

import argparse
import json
import math
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

KEY = "bench/ros2"
MODES = ("ros2", "envelope", "raw")
TYPES = ("std_msgs/msg/String", "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu",
         "sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/CompressedImage")
_STAMP = struct.Struct("<q")


def sample(name: str) -> Any:
    """A filled message of the ROS 2 type ``name`` (a 64 KB JPEG-sized image for CompressedImage)."""
    from zenoh_robot.ros2 import ros2_type

    msg: Any = ros2_type(name)()
    if name.endswith("String"):
        msg.data = "x" * 64
    elif name.endswith("CompressedImage"):
        msg.format, msg.data = "jpeg", bytes(range(256)) * 256
    if hasattr(msg, "header"):
        msg.header.frame_id = "base_link"
        msg.header.stamp.sec = 1_700_000_000
    if name.endswith("Imu"):
        msg.orientation_covariance = [0.1] * 9
        msg.linear_acceleration.z = 9.81
    if name.endswith("PoseStamped"):
        msg.pose.position.x, msg.pose.orientation.w = 1.5, 1.0
    return msg


def _per_call_us(fn: Callable[[], Any], budget_s: float) -> float:
    n, t0 = 0, time.perf_counter()
    while True:
        fn()
        n += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= budget_s and n >= 20:
            return elapsed / n * 1e6


def codec_figures(budget_s: float = 0.3) -> list[dict[str, Any]]:
    """Per type: bytes and µs per encode/decode, CDR and the envelope's msgpack body."""
    import msgpack

    from zenoh_robot.message import type_support
    from zenoh_robot.ros2 import cdr_codec

    rows = []
    for name in TYPES:
        msg = sample(name)
        ts, codec = type_support(type(msg)), cdr_codec(type(msg))
        cdr = codec.serialize(ts.encode(msg))
        packed = msgpack.packb(ts.encode(msg), use_bin_type=True)
        assert ts.decode(codec.deserialize(cdr)) == msg
        rows.append({"type": name, "cdr_bytes": len(cdr), "msgpack_bytes": len(packed),
                     **_timings(msg, ts, codec, cdr, packed, budget_s)})
    return rows


def _timings(msg: Any, ts: Any, codec: Any, cdr: bytes, packed: bytes, budget_s: float) -> dict[str, float]:
    import msgpack

    return {"cdr_encode_us": _per_call_us(lambda: codec.serialize(ts.encode(msg)), budget_s),
            "cdr_decode_us": _per_call_us(lambda: ts.decode(codec.deserialize(cdr)), budget_s),
            "msgpack_encode_us": _per_call_us(lambda: msgpack.packb(ts.encode(msg), use_bin_type=True), budget_s),
            "msgpack_decode_us": _per_call_us(lambda: ts.decode(msgpack.unpackb(packed, raw=False)), budget_s)}


# -- end to end: one side per process -------------------------------------------------------------
def _config(port: int, role: str) -> Any:
    from zenoh_robot import SessionConfig

    endpoint = [f"tcp/127.0.0.1:{port}"]
    if role == "sub":
        return SessionConfig(listen=endpoint, multicast_scouting=False, shared_memory=False)
    return SessionConfig(listen=[], connect=endpoint, multicast_scouting=False, shared_memory=False)


def _qos(throughput: bool) -> Any:
    from zenoh_robot import HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_ALL if throughput else HistoryPolicy.KEEP_LAST,
                      depth=0 if throughput else 100)


def _wire(mode: str) -> Any:
    from zenoh_robot.wire import ENVELOPE, ros2_wire

    return ros2_wire(0) if mode == "ros2" else ENVELOPE


def run_sub(args: argparse.Namespace) -> dict[str, Any]:
    import zenoh

    from zenoh_robot import Node
    from zenoh_robot.message import type_support
    from zenoh_robot.ros2 import cdr_codec

    cls = type(sample(args.type))
    ages: list[float] = []
    first = last = 0.0
    done = threading.Event()

    def record(stamp_ns: int) -> None:
        nonlocal first, last
        now = time.time_ns()
        ages.append((now - stamp_ns) / 1e6)
        last = now / 1e9
        if len(ages) == 1:
            first = last
        if len(ages) >= args.count:
            done.set()

    cfg = _config(args.port, "sub")
    if args.mode == "raw":
        ts, deserialize = type_support(cls), cdr_codec(cls).deserialize
        with zenoh.open(cfg.to_zenoh()) as session:
            def on_sample(s: Any) -> None:
                data = s.payload.to_bytes()
                ts.decode(deserialize(data[_STAMP.size:]))   # the decoding work the nodes do
                record(_STAMP.unpack_from(data)[0])
            session.declare_subscriber(KEY, on_sample)
            print("READY", flush=True)
            done.wait(args.timeout)
    else:
        with Node("bench_sub", config=cfg, wire=_wire(args.mode)) as node:
            node.create_subscription(cls, "/" + KEY, lambda m, info: record(info.source_stamp_ns),
                                     _qos(args.throughput))
            threading.Thread(target=node.spin, daemon=True).start()
            print("READY", flush=True)
            done.wait(args.timeout)
            node.shutdown()
    return {"received": len(ages), "ages_ms": ages, "t_first": first, "t_last": last}


def run_pub(args: argparse.Namespace) -> dict[str, Any]:
    import zenoh

    from zenoh_robot import Node
    from zenoh_robot.message import type_support
    from zenoh_robot.ros2 import cdr_codec

    msg = sample(args.type)
    period = 1.0 / args.rate if args.rate > 0 else 0.0
    cfg = _config(args.port, "pub")
    if args.mode == "raw":
        body = cdr_codec(type(msg)).serialize(type_support(type(msg)).encode(msg))
        with zenoh.open(cfg.to_zenoh()) as session:
            cc = zenoh.CongestionControl.BLOCK if args.throughput else zenoh.CongestionControl.DROP
            zpub = session.declare_publisher(KEY, reliability=zenoh.Reliability.RELIABLE, congestion_control=cc)
            time.sleep(1.0)
            _loop(lambda: zpub.put(_STAMP.pack(time.time_ns()) + body), args.count, period)
            time.sleep(0.5)
    else:
        with Node("bench_pub", config=cfg, wire=_wire(args.mode)) as node:
            pub = node.create_publisher(type(msg), "/" + KEY, _qos(args.throughput))
            time.sleep(1.0)
            _loop(lambda: pub.publish(msg), args.count, period)
            time.sleep(0.5)   # let the tail leave before the session closes
    return {"sent": args.count}


def _loop(send: Callable[[], Any], count: int, period: float) -> None:
    t0 = time.monotonic()
    for i in range(count):
        send()
        if period:
            delay = t0 + (i + 1) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def run_pair(mode: str, type_name: str, count: int, rate: float) -> dict[str, Any]:
    """One end-to-end cell: figures (received, p50_ms, p99_ms, msgs_per_s) or an error."""
    import numpy as np

    port = _free_port()
    common = [mode, type_name, "--count", str(count), "--port", str(port)] + (["--throughput"] if not rate else [])
    me = [sys.executable, "-m", "zenoh_robot.tools.bench.ros2", "--worker"]
    timeout = count / rate * 2 + 30 if rate else 90.0
    sub = subprocess.Popen([*me, "sub", *common, "--timeout", str(timeout)], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        assert sub.stdout is not None and sub.stderr is not None
        if sub.stdout.readline().strip() != "READY":
            return {"error": f"subscriber did not start: {sub.stderr.read()[-300:]}"}
        pub = subprocess.run([*me, "pub", *common, "--rate", str(rate)], capture_output=True, text=True,
                             timeout=timeout + 30)
        out, err = sub.communicate(timeout=timeout + 30)
    finally:
        if sub.poll() is None:
            sub.kill()
    if pub.returncode or sub.returncode:
        return {"error": f"worker failed: {(pub.stderr or err)[-300:]}"}
    s = json.loads(out.strip().splitlines()[-1])
    ages = np.array(s["ages_ms"])
    fig: dict[str, Any] = {"received": s["received"], "sent": count, "p50_ms": math.nan, "p99_ms": math.nan,
                           "msgs_per_s": math.nan}
    if ages.size:
        fig["p50_ms"], fig["p99_ms"] = float(np.percentile(ages, 50)), float(np.percentile(ages, 99))
    if s["received"] > 1 and s["t_last"] > s["t_first"]:
        fig["msgs_per_s"] = (s["received"] - 1) / (s["t_last"] - s["t_first"])
    return fig


def end_to_end(quick: bool = False, type_name: str = "geometry_msgs/msg/PoseStamped") -> list[dict[str, Any]]:
    """Latency (200 Hz) and throughput cells, each mode in turn, with ratios to raw."""
    scale = 0.2 if quick else 1.0
    rows = []
    for kind, rate, count in (("latency", 200.0, int(2000 * scale)), ("throughput", 0.0, int(20000 * scale))):
        figs = {mode: run_pair(mode, type_name, count, rate) for mode in MODES}
        raw = figs["raw"]
        for mode in MODES:
            f = figs[mode]
            if kind == "latency":
                f["ratio_p50"] = f.get("p50_ms", math.nan) / raw["p50_ms"] if raw.get("p50_ms") else math.nan
            else:
                f["ratio_throughput"] = (f.get("msgs_per_s", math.nan) / raw["msgs_per_s"]
                                         if raw.get("msgs_per_s") else math.nan)
            rows.append({"kind": kind, "rate_hz": rate, "type": type_name, "mode": mode, **f})
    return rows


def markdown(codec: list[dict[str, Any]], e2e: list[dict[str, Any]]) -> str:
    lines = ["## ROS 2 wire: codec (µs per message, this process)", "",
             "| type | CDR bytes | CDR enc | CDR dec | msgpack bytes | msgpack enc | msgpack dec |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['type']} | {r['cdr_bytes']} | {r['cdr_encode_us']:.1f} | {r['cdr_decode_us']:.1f} | "
              f"{r['msgpack_bytes']} | {r['msgpack_encode_us']:.1f} | {r['msgpack_decode_us']:.1f} |" for r in codec]
    lines += ["", "## ROS 2 wire: end to end (two processes, TCP loopback)", "",
              "| cell | mode | received | p50 ms | p99 ms | msg/s | vs raw |", "|---|---|---|---|---|---|---|"]
    for r in e2e:
        cell = f"{r['kind']} {r['rate_hz']:g} Hz" if r["rate_hz"] else r["kind"]
        ratio = r.get("ratio_p50", r.get("ratio_throughput", math.nan))
        if r.get("error"):
            lines.append(f"| {cell} | {r['mode']} | error: {r['error'][:80]} | | | | |")
            continue
        lines.append(f"| {cell} | {r['mode']} | {r['received']}/{r['sent']} | {r['p50_ms']:.2f} | "
                     f"{r['p99_ms']:.2f} | {r['msgs_per_s']:.0f} | {ratio:.2f}x |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zenoh_robot.tools.bench.ros2")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--quick", action="store_true", help="a fifth of the messages")
    p.add_argument("rest", nargs="*", help=argparse.SUPPRESS)
    args, extra = p.parse_known_args(argv)
    if args.worker:
        w = argparse.ArgumentParser()
        w.add_argument("role", choices=("pub", "sub"))
        w.add_argument("mode", choices=MODES)
        w.add_argument("type")
        w.add_argument("--count", type=int, required=True)
        w.add_argument("--port", type=int, required=True)
        w.add_argument("--rate", type=float, default=0.0)
        w.add_argument("--throughput", action="store_true")
        w.add_argument("--timeout", type=float, default=60.0)
        wargs = w.parse_args([*args.rest, *extra])
        out = run_sub(wargs) if wargs.role == "sub" else run_pub(wargs)
        print(json.dumps(out), flush=True)
        return 0
    print(markdown(codec_figures(), end_to_end(args.quick)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
