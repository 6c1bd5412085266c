"""``zenoh-robot bench --ros2``: the ROS 2 wire beside the envelope and raw zenoh-python.

Two parts. **Codec**: per ROS 2 type, in this process, the time to turn a message into its wire
bytes and back: CDR (the ROS 2 wire: the type's generated codec, ``zenoh_robot/ros2/fastcdr.py``,
and back with field validation), rosbags alone (the reference, as before the fast path), and the
envelope's msgpack body of the same class. **End to end**: two processes over TCP loopback, one
ROS 2 class per cell (PoseStamped at 200 Hz and flat out, a 64 KB CompressedImage at 30 Hz)
published by a Node on the ROS 2 wire, by a Node on the envelope, by zenoh-ros2-sdk (the other Python
implementation of rmw_zenoh's wire, ``ros2_sdk.py``), and as raw zenoh-python puts of its CDR bytes with
rmw_zenoh's 33-byte attachment (the stamp in it), whose subscriber decodes as the nodes do: the same
bytes on the wire as the ROS 2 mode, the physical limit: p50/p99 age at a fixed rate, messages per
second as fast as reliable KEEP_ALL allows, and each side's CPU per message (all its threads). The modes
alternate within each repetition (ros2, envelope, sdk, raw, ros2, ...) so a shared machine's load falls
on all alike; ratios are each repetition's own, their median and spread reported with the load average.
``--codec rosbags`` runs every process without the fast path (the "before"). Run alone:
``python -m zenoh_robot.tools.bench.ros2 [--quick] [--reps N] [--receive channel] [--json PATH]``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from . import ros2_sdk

KEY = "bench/ros2"
MODES = ("ros2", "envelope", "sdk", "raw")
TYPES = ("std_msgs/msg/String", "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/Imu",
         "sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/CompressedImage")
# rmw_zenoh's attachment (seq, source stamp, 16, GID): raw zenoh-python sends what the ROS 2 wire sends.
_ATTACHMENT = struct.Struct("<qqB16s")


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


def _rosbags_only(type_name: str) -> None:
    """This process's codec of ``type_name`` without its generated fast path (the "before" of a bench)."""
    from zenoh_robot.ros2 import cdr_codec, ros2_type

    codec: Any = cdr_codec(ros2_type(type_name))
    codec._fast_encode = codec._fast_decode = None


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
            "rosbags_encode_us": _per_call_us(lambda: codec.serialize_rosbags(ts.encode(msg)), budget_s),
            "rosbags_decode_us": _per_call_us(lambda: ts.decode(codec.deserialize_rosbags(cdr)), budget_s),
            "msgpack_encode_us": _per_call_us(lambda: msgpack.packb(ts.encode(msg), use_bin_type=True), budget_s),
            "msgpack_decode_us": _per_call_us(lambda: ts.decode(msgpack.unpackb(packed, raw=False)), budget_s)}


# -- end to end: one side per process -------------------------------------------------------------
def _sample_cdr(name: str) -> bytes:
    """The CDR bytes of :func:`sample` of ``name`` (what zenoh-ros2-sdk's side builds its messages from)."""
    from zenoh_robot.message import type_support
    from zenoh_robot.ros2 import cdr_codec

    msg = sample(name)
    data: bytes = cdr_codec(type(msg)).serialize(type_support(type(msg)).encode(msg))
    return data


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
    cpu_first = math.nan
    done = threading.Event()

    def record(stamp_ns: int) -> None:
        nonlocal first, last, cpu_first
        now = time.time_ns()
        ages.append((now - stamp_ns) / 1e6)
        last = now / 1e9
        if len(ages) == 1:
            first = last
            cpu_first = time.process_time()
        if len(ages) >= args.count:
            done.set()

    cfg = _config(args.port, "sub")
    cpu0 = 0.0
    if args.mode == "sdk":
        sub = ros2_sdk.subscribe(args.type, args.port, args.throughput, _sample_cdr(args.type), record)
        print("READY", flush=True)
        cpu0 = time.process_time()
        done.wait(args.timeout)
        sub.close()
    elif args.mode == "raw":
        ts, deserialize = type_support(cls), cdr_codec(cls).deserialize
        with zenoh.open(cfg.to_zenoh()) as session:
            def on_sample(s: Any) -> None:
                ts.decode(deserialize(s.payload.to_bytes()))     # the decoding work the nodes do
                record(_ATTACHMENT.unpack_from(s.attachment.to_bytes())[1])
            session.declare_subscriber(KEY, on_sample)
            print("READY", flush=True)
            cpu0 = time.process_time()
            done.wait(args.timeout)
    else:
        with Node("bench_sub", config=cfg, wire=_wire(args.mode)) as node:
            node.create_subscription(cls, "/" + KEY, lambda m, info: record(info.source_stamp_ns),
                                     _qos(args.throughput), receive=args.receive)
            threading.Thread(target=node.spin, daemon=True).start()
            print("READY", flush=True)
            cpu0 = time.process_time()
            done.wait(args.timeout)
            node.shutdown()
    # Per-message CPU counts the flow after the first sample (every thread of the process), as the main bench's
    # worker does: not imports, set-up or the publisher's discovery.
    end = time.process_time()
    return {"received": len(ages), "ages_ms": ages, "t_first": first, "t_last": last,
            "cpu_s": end - cpu_first if ages else end - cpu0}


def run_pub(args: argparse.Namespace) -> dict[str, Any]:
    import zenoh

    from zenoh_robot import Node
    from zenoh_robot.message import type_support
    from zenoh_robot.ros2 import cdr_codec

    msg = sample(args.type)
    period = 1.0 / args.rate if args.rate > 0 else 0.0
    cfg = _config(args.port, "pub")
    cpu = 0.0
    if args.mode == "sdk":
        send = ros2_sdk.publisher(args.type, args.port, args.throughput, _sample_cdr(args.type))
        time.sleep(1.0)
        cpu = _timed_loop(send, args.count, period)
        time.sleep(0.5)
    elif args.mode == "raw":
        # Serialised per publish, as a node does (and as the raw subscriber decodes per sample).
        serialize, encode = cdr_codec(type(msg)).serialize, type_support(type(msg)).encode
        with zenoh.open(cfg.to_zenoh()) as session:
            cc = zenoh.CongestionControl.BLOCK if args.throughput else zenoh.CongestionControl.DROP
            zpub = session.declare_publisher(KEY, reliability=zenoh.Reliability.RELIABLE, congestion_control=cc)
            time.sleep(1.0)
            seq = iter(range(1, args.count + 1))
            gid = bytes(range(16))

            def send() -> None:
                # Stamped where a Node's publish stamps (publisher.py): after the message's field values
                # are taken, before the CDR is written; so both ages hold the same work.
                body = encode(msg)
                stamp = time.time_ns()
                zpub.put(serialize(body), attachment=_ATTACHMENT.pack(next(seq), stamp, 16, gid))
            cpu = _timed_loop(send, args.count, period)
            time.sleep(0.5)
    else:
        with Node("bench_pub", config=cfg, wire=_wire(args.mode)) as node:
            pub = node.create_publisher(type(msg), "/" + KEY, _qos(args.throughput))
            time.sleep(1.0)
            cpu = _timed_loop(lambda: pub.publish(msg), args.count, period)
            time.sleep(0.5)   # let the tail leave before the session closes
    return {"sent": args.count, "cpu_s": cpu}


def _timed_loop(send: Callable[[], Any], count: int, period: float) -> float:
    """The publish loop; returns the process's CPU seconds over it (every thread)."""
    cpu0 = time.process_time()
    _loop(send, count, period)
    return time.process_time() - cpu0


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


def run_pair(mode: str, type_name: str, count: int, rate: float, receive: str | None = None,
             codec: str = "fast") -> dict[str, Any]:
    """One end-to-end run: figures (received, p50_ms, p99_ms, msgs_per_s) or an error."""
    import numpy as np

    if mode == "sdk" and not ros2_sdk.available():
        return {"error": ros2_sdk.MISSING}
    port = _free_port()
    common = [mode, type_name, "--count", str(count), "--port", str(port), "--codec", codec]
    common += (["--throughput"] if not rate else []) + (["--receive", receive] if receive else [])
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
    s, p = json.loads(out.strip().splitlines()[-1]), json.loads(pub.stdout.strip().splitlines()[-1])
    ages = np.array(s["ages_ms"])
    fig: dict[str, Any] = {"received": s["received"], "sent": count, "p50_ms": math.nan, "p99_ms": math.nan,
                           "msgs_per_s": math.nan, "cpu_us_sub": s["cpu_s"] / max(s["received"] - 1, 1) * 1e6,
                           "cpu_us_pub": p["cpu_s"] / count * 1e6}
    if ages.size:
        fig["p50_ms"], fig["p99_ms"] = float(np.percentile(ages, 50)), float(np.percentile(ages, 99))
    if s["received"] > 1 and s["t_last"] > s["t_first"]:
        fig["msgs_per_s"] = (s["received"] - 1) / (s["t_last"] - s["t_first"])
    return fig


# (type, kind, rate Hz, count): a small message at a fixed rate and flat out, and a JPEG-sized image.
CELLS = (("geometry_msgs/msg/PoseStamped", "latency", 200.0, 1000), ("geometry_msgs/msg/PoseStamped", "throughput",
                                                                    0.0, 10000),
         ("sensor_msgs/msg/CompressedImage", "latency", 30.0, 150))


def _per_rep(figs: list[dict[str, Any]], runs: list[dict[str, dict[str, Any]]], name: str) -> list[float]:
    """Each repetition's figure ``name`` over its own raw run's (repetitions with an error left out)."""
    out = [f.get(name, math.nan) / r["raw"].get(name, math.nan) for f, r in zip(figs, runs, strict=True)
           if not f.get("error") and not r["raw"].get("error")]
    return [x for x in out if math.isfinite(x)]


def end_to_end(quick: bool = False, reps: int = 5, receive: str | None = None, codec: str = "fast",
               cells: tuple[tuple[str, str, float, int], ...] = CELLS) -> list[dict[str, Any]]:
    """Per cell and mode: median figures of ``reps`` repetitions that alternate the modes (ros2, envelope,
    sdk, raw, ros2, ...), each repetition's ratio to its own raw run (median and spread), the load average."""
    import numpy as np

    rows = []
    for type_name, kind, rate, full in cells:
        count = max(50, int(full * (0.2 if quick else 1.0)))
        runs: list[dict[str, dict[str, Any]]] = []
        loads: list[float] = []
        for _ in range(max(1, reps)):
            runs.append({mode: run_pair(mode, type_name, count, rate, receive, codec) for mode in MODES})
            loads.append(os.getloadavg()[0])
        key = "p50_ms" if kind == "latency" else "msgs_per_s"
        for mode in MODES:
            figs = [r[mode] for r in runs]
            ratios, cpu_ratios = _per_rep(figs, runs, key), _per_rep(figs, runs, "cpu_us_sub")

            def med(name: str, figs: list[dict[str, Any]] = figs) -> float:
                vals = [f[name] for f in figs if not f.get("error") and math.isfinite(f.get(name, math.nan))]
                return float(np.median(vals)) if vals else math.nan
            rows.append({"kind": kind, "rate_hz": rate, "type": type_name, "mode": mode, "reps": len(figs),
                         "received": min(f.get("received", 0) for f in figs), "sent": count,
                         "p50_ms": med("p50_ms"), "p99_ms": med("p99_ms"), "msgs_per_s": med("msgs_per_s"),
                         "cpu_us_sub": med("cpu_us_sub"), "cpu_us_pub": med("cpu_us_pub"),
                         "cpu_sub_ratio": float(np.median(cpu_ratios)) if cpu_ratios else math.nan,
                         "ratio": float(np.median(ratios)) if ratios else math.nan,
                         "ratio_low": min(ratios, default=math.nan), "ratio_high": max(ratios, default=math.nan),
                         "load": [min(loads), max(loads)], "receive": receive or "default", "codec": codec,
                         "error": next((f["error"] for f in figs if f.get("error")), ""), "runs": figs})
    return rows


def markdown(codec: list[dict[str, Any]], e2e: list[dict[str, Any]]) -> str:
    lines = ["## ROS 2 wire: codec (µs per message, this process)", "",
             "| type | CDR bytes | CDR enc | CDR dec | rosbags enc | rosbags dec | msgpack bytes | msgpack enc | "
             "msgpack dec |", "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['type']} | {r['cdr_bytes']} | {r['cdr_encode_us']:.1f} | {r['cdr_decode_us']:.1f} | "
              f"{r['rosbags_encode_us']:.1f} | {r['rosbags_decode_us']:.1f} | "
              f"{r['msgpack_bytes']} | {r['msgpack_encode_us']:.1f} | {r['msgpack_decode_us']:.1f} |" for r in codec]
    lines += ["", "## ROS 2 wire: end to end (two processes, TCP loopback, modes alternating)", "",
              "| cell | mode | received | p50 ms | p99 ms | msg/s | vs raw: median (spread) | "
              "sub CPU µs/msg (vs raw) | pub CPU µs/msg | reps | load |", "|---" * 11 + "|"]
    for r in e2e:
        short = r["type"].rsplit("/", 1)[-1]
        cell = f"{short} {r['kind']} {r['rate_hz']:g} Hz" if r["rate_hz"] else f"{short} {r['kind']}"
        if r.get("error"):
            lines.append(f"| {cell} | {r['mode']} | error: {r['error'][:80]} | | | | | | | | |")
            continue
        lines.append(f"| {cell} | {r['mode']} | {r['received']}/{r['sent']} | {r['p50_ms']:.3f} | "
                     f"{r['p99_ms']:.2f} | {r['msgs_per_s']:.0f} | {r['ratio']:.2f} ({r['ratio_low']:.2f}-"
                     f"{r['ratio_high']:.2f}) | {r['cpu_us_sub']:.1f} ({r['cpu_sub_ratio']:.2f}) | "
                     f"{r['cpu_us_pub']:.1f} | {r['reps']} | {r['load'][0]:.1f}-{r['load'][1]:.1f} |")
    return "\n".join(lines)


def write_json(path: Path, codec: list[dict[str, Any]], e2e: list[dict[str, Any]]) -> None:
    """The raw figures of one run (every repetition's, ages aside), with the machine's load and time."""
    import datetime
    import platform

    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"when": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "host_cpus": os.cpu_count(), "python": platform.python_version(), "load_end": os.getloadavg()}
    path.write_text(json.dumps({"meta": meta, "codec": codec, "end_to_end": e2e}, indent=1))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zenoh_robot.tools.bench.ros2")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--quick", action="store_true", help="a fifth of the messages")
    p.add_argument("--reps", type=int, default=5, help="alternating repetitions per cell")
    p.add_argument("--receive", choices=("callback", "channel"), default=None, help="the nodes' receive path")
    p.add_argument("--codec", choices=("fast", "rosbags"), default="fast",
                   help="CDR through the generated codec (the library's) or rosbags alone (as before #27's fast path)")
    p.add_argument("--json", type=Path, default=None, help="also write the raw figures here")
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
        w.add_argument("--receive", choices=("callback", "channel"), default=None)
        w.add_argument("--codec", choices=("fast", "rosbags"), default="fast")
        wargs = w.parse_args([*args.rest, *extra])
        if wargs.codec == "rosbags":
            _rosbags_only(wargs.type)
        out = run_sub(wargs) if wargs.role == "sub" else run_pub(wargs)
        print(json.dumps(out), flush=True)
        if wargs.mode == "sdk":
            os._exit(0)     # zenoh-ros2-sdk's session threads keep the process alive past its figures
        return 0
    codec, e2e = codec_figures(), end_to_end(args.quick, args.reps, args.receive, args.codec)
    print(markdown(codec, e2e))
    if args.json is not None:
        write_json(args.json, codec, e2e)
    return 0


if __name__ == "__main__":
    sys.exit(main())
