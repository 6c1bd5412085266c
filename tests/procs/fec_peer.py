"""One side of a lossy FEC image cell over the resilient multicast transport; prints a JSON summary."""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from zenoh_robot import Node, SessionConfig
from zenoh_robot.image.fec import FecImagePublisher, FecImageSubscription
from zenoh_robot.qos import IMAGE

p = argparse.ArgumentParser()
p.add_argument("role", choices=["pub", "sub"])
p.add_argument("--ns", required=True)
p.add_argument("--iface", required=True)
p.add_argument("--loss", type=float, default=0.3, help="loss the parity is sized for (0..1)")
p.add_argument("--fps", type=float, default=30.0)
p.add_argument("--duration", type=float, default=4.0)
p.add_argument("--stop-file", help="receive until this file exists (the publisher has finished); "
               "--duration caps the wait")
p.add_argument("--start-file")
args = p.parse_args()

cfg = SessionConfig.resilient(args.iface, "239.255.74.79:7460")
with Node(args.role, namespace=args.ns, config=cfg) as node:
    if args.role == "pub":
        pub = FecImagePublisher(node, "image", IMAGE, quality=60, loss=args.loss)
        print("READY", flush=True)
        while args.start_file and not os.path.exists(args.start_file):
            time.sleep(0.05)
        y, x = np.mgrid[0:240, 0:320]
        n = int(args.duration * args.fps)
        t0 = time.monotonic()
        for i in range(n):
            frame = np.stack([(x + 4 * i) % 256, (y + 2 * i) % 256, ((x * y) // 97 + i) % 256], axis=2)
            pub.publish(frame.astype(np.uint8))
            time.sleep(max(0.0, t0 + (i + 1) / args.fps - time.monotonic()))
        print(json.dumps({"sent": n, "k": pub.last_k, "n": pub.last_n}), flush=True)
        time.sleep(1.0)
    else:
        frames: list[int] = []
        sub = FecImageSubscription(node, "image", lambda img, info: frames.append(info.frame))
        print("READY", flush=True)
        # Until the test says the publisher is done: a receiver timed from its own start ends early
        # when a loaded machine slows the publisher's start, and the tail reads as lost.
        node.spin_until(lambda: bool(args.stop_file) and os.path.exists(args.stop_file), timeout=args.duration)
        print(json.dumps({"frames": frames, "share_loss": sub.assembler.loss,
                          "decode_errors": sub.assembler.decode_errors}), flush=True)
