"""A publisher in its own process: Setpoints on <ns>/setpoint at a rate, for the cross-process tests."""
from __future__ import annotations

import argparse
import time

from zenoh_robot import Node, QoSProfile
from zenoh_robot.msgs import Header, Setpoint

parser = argparse.ArgumentParser()
parser.add_argument("--ns", required=True)
parser.add_argument("--count", type=int, default=50)
parser.add_argument("--rate", type=float, default=50.0)
parser.add_argument("--reliability", default="reliable")
args = parser.parse_args()

with Node("talker", namespace=args.ns) as node:
    pub = node.create_publisher(Setpoint, "setpoint", QoSProfile(reliability=args.reliability, depth=100))
    print("READY", flush=True)
    time.sleep(1.0)  # let the subscriber's session find ours
    for i in range(args.count):
        pub.publish(Setpoint(Header.now(seq=i), x=float(i), y=1.0, z=-2.0))
        time.sleep(1.0 / args.rate)
    time.sleep(0.5)
    print("DONE", flush=True)
