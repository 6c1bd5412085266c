"""Per-sample Python cost of the default (callback) receive path and of ``publish()``, in one process, against
the raw zenoh-python baseline's own work: ``python -m zenoh_robot.tools.bench.persample [setpoint|sensor]``.

No network and no second thread, so what is left is the Python a sample costs on each side (issue #43):

- ``publish``: ``Publisher.publish`` on a session with no peer (encode, lock, sequence, stamp, pack, put,
  ``PublishInfo``); ``raw publish``: the bench's raw publisher (encode, stamp, ``msgpack.packb``, put).
- ``zenoh thread``: ``Subscription._on_sample`` with a stand-in sample (copy, stamp, bounded queue).
- ``executor``: the drain of those samples (envelope checks, type hash, sequence, ``MessageInfo``, a
  2-argument callback); ``raw callback``: the bench's raw subscriber callback (``unpackb``, the body's decode).

Figures are CPU time of this thread (``time.thread_time``), medians over alternating repetitions, so a busy
machine moves them less than wall time would; they are not the end-to-end figures of ``zenoh-robot bench``.
"""
from __future__ import annotations

import argparse
import gc
import statistics
import time
from collections.abc import Callable
from typing import Any

import msgpack
import zenoh

from zenoh_robot import HistoryPolicy, Node, QoSProfile, ReliabilityPolicy, SessionConfig
from zenoh_robot.message import type_support

from . import payloads


class _Sample:
    """What ``_on_sample`` reads of a ``zenoh.Sample``."""
    __slots__ = ("payload", "attachment")

    def __init__(self, payload: bytes) -> None:
        self.payload = zenoh.ZBytes(payload)
        self.attachment = None


def measure(payload: str = "setpoint", count: int = 20_000, reps: int = 9) -> dict[str, float]:
    """Median microseconds per sample of each step (see the module doc)."""
    msg = payloads.make(payload)
    ts = type_support(type(msg))
    keep_all = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL, depth=0)
    config = SessionConfig(listen=[], multicast_scouting=False, shared_memory=False)
    runs: dict[str, list[float]] = {}

    def timed(name: str, fn: Callable[[], Any]) -> None:
        gc.collect()
        start = time.thread_time()
        fn()
        runs.setdefault(name, []).append((time.thread_time() - start) / count * 1e6)

    with Node("persample", config=config) as node:
        pub = node.create_publisher(type(msg), "/bench/persample", keep_all)
        raw_pub = node.session.declare_publisher("bench/persample_raw")
        samples = [_Sample(pub._pack(i + 1, time.time_ns(), ts.encode(msg), None)) for i in range(count)]
        raw_payloads = [zenoh.ZBytes(msgpack.packb((time.time_ns(), ts.encode(msg)), use_bin_type=True))
                        for _ in range(count)]
        sub = node.create_subscription(type(msg), "/bench/persample_sub", lambda m, info: None, keep_all)
        sub.max_queued_bytes = 1 << 40      # all `count` samples queued at once, none dropped:
        sub._limit = max(sub._limit, count)     # over KEEP_ALL's 10,000 too

        def publish() -> None:
            send = pub.publish
            for _ in range(count):
                send(msg)

        def raw_publish() -> None:
            encode, put, packb, now = ts.encode, raw_pub.put, msgpack.packb, time.time_ns
            for _ in range(count):
                body = encode(msg)
                put(packb((now(), body), use_bin_type=True))

        def zenoh_thread() -> None:
            on_sample = sub._on_sample
            for sample in samples:
                on_sample(sample)

        def executor() -> None:
            while sub._drain_some():
                pass

        def raw_callback() -> None:
            decode, unpackb, now = ts.decode, msgpack.unpackb, time.time_ns
            for zbytes in raw_payloads:
                values = unpackb(zbytes.to_bytes())
                decode(values[1])
                now()

        for _ in range(reps):
            sub.counters.per_publisher_seq.clear()      # each repetition's sequence numbers start again at 1
            sub._seq_newest = None
            timed("publish", publish)
            timed("raw publish", raw_publish)
            timed("zenoh thread", zenoh_thread)
            timed("executor", executor)
            timed("raw callback", raw_callback)
        while node.executor.spin_once(0):     # the drains the samples submitted: nothing left to run
            pass
        if sub.counters.delivered != reps * count or sub.counters.lost:
            raise RuntimeError(f"per-sample bench lost samples: {sub.counters}")
        raw_pub.undeclare()
    out = {name: statistics.median(values) for name, values in runs.items()}
    out["receive"] = out["zenoh thread"] + out["executor"]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("payloads", nargs="*", help="setpoint, sensor (default: both)")
    p.add_argument("--count", type=int, default=20_000)
    p.add_argument("--reps", type=int, default=9)
    args = p.parse_args(argv)
    zenoh.init_log_from_env_or("error")
    for name in args.payloads or ["setpoint", "sensor"]:
        f = measure(name, args.count, args.reps)
        print(f"{name}: publish {f['publish']:.2f} us (raw {f['raw publish']:.2f}, "
              f"{f['publish'] / f['raw publish']:.2f}x); receive {f['receive']:.2f} us = Zenoh thread "
              f"{f['zenoh thread']:.2f} + executor {f['executor']:.2f} "
              f"(raw callback {f['raw callback']:.2f}, {f['receive'] / f['raw callback']:.2f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
