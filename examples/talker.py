"""Publish setpoints at 10 Hz: x increasing, y and z constant (the thesis's advertiser)."""
import argparse

from zenoh_robot import Node, qos
from zenoh_robot.msgs import Header, Setpoint

parser = argparse.ArgumentParser(description=__doc__)
parser.add_argument("--ns", default="demo")
parser.add_argument("--rate", type=float, default=10.0)
args = parser.parse_args()

with Node("talker", namespace=args.ns) as node:
    # Offers a 0.5 s deadline and a 1 s liveliness lease: subscriptions may request either, or longer.
    pub = node.create_publisher(Setpoint, "setpoint", qos.SETPOINT.replace(deadline=0.5, liveliness_lease_duration=1.0))
    seq = 0

    def tick() -> None:
        global seq
        pub.publish(Setpoint(Header.now(seq=seq), x=0.1 * seq, y=1.0, z=-2.0))
        seq += 1

    node.create_timer(1.0 / args.rate, tick)
    node.spin()
