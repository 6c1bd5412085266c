"""One side of a lossy-link cell: publish or receive setpoints, print a JSON summary."""
from __future__ import annotations

import argparse
import json
import os
import time

from zenoh_robot import Node, SessionConfig, qos
from zenoh_robot.msgs import Header, Setpoint

p = argparse.ArgumentParser()
p.add_argument("role", choices=["pub", "sub"])
p.add_argument("--ns", required=True)
p.add_argument("--profile", default="setpoint")
p.add_argument("--listen", action="append", default=[])
p.add_argument("--connect", action="append", default=[])
p.add_argument("--rate", type=float, default=20.0)
p.add_argument("--duration", type=float, default=5.0)
p.add_argument("--stop-file", help="receive until this file exists (the publisher has finished); "
               "--duration caps the wait")
p.add_argument("--start-file", help="publish only once this file exists (loss is in place)")
args = p.parse_args()

cfg = SessionConfig(listen=args.listen, connect=args.connect, multicast_scouting=False, shared_memory=False)
profile = qos.preset(args.profile)
with Node(args.role, namespace=args.ns, config=cfg) as node:
    # Both links (TCP for reliable, UDP for best effort) must be up before loss starts, or
    # best effort silently rides the TCP link and the cell measures the wrong transport.
    deadline = time.monotonic() + 10
    while len(node.session.info.links()) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    if args.role == "pub":
        pub = node.create_publisher(Setpoint, "setpoint", profile)
        print("READY", flush=True)
        if args.start_file:
            while not os.path.exists(args.start_file):
                time.sleep(0.05)
        n = int(args.duration * args.rate)
        t0 = time.monotonic()
        for i in range(n):
            pub.publish(Setpoint(Header.now(seq=i), x=float(i)))
            time.sleep(max(0.0, t0 + (i + 1) / args.rate - time.monotonic()))
        print(json.dumps({"sent": n}), flush=True)
        time.sleep(1.0)
    else:
        seqs: list[int] = []
        arrivals: list[float] = []
        sub = node.create_subscription(Setpoint, "setpoint",
                                       lambda m: (seqs.append(m.header.seq), arrivals.append(time.monotonic())),
                                       profile.replace(depth=100))
        print("READY", flush=True)
        # Until the test says the publisher is done: a receiver timed from its own start ends early
        # when a loaded machine slows the publisher's start, and the tail reads as lost.
        node.spin_until(lambda: bool(args.stop_file) and os.path.exists(args.stop_file), timeout=args.duration)
        gaps = [b - a for a, b in zip(arrivals, arrivals[1:], strict=False)]
        print(json.dumps({"seqs": seqs, "max_gap": max(gaps) if gaps else None}), flush=True)
