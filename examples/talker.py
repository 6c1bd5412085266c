"""Publish setpoints at 10 Hz: x increasing, y and z constant (the thesis's advertiser)."""
from __future__ import annotations

import argparse

from zenoh_robot import Node, SessionConfig, qos
from zenoh_robot.msgs import Header, Setpoint
from zenoh_robot.session_args import add_session_arguments, session_config_from_args


def main(conf: SessionConfig, ns: str, rate: float) -> None:
    with Node("talker", namespace=ns, config=conf) as node:
        # Offers a 0.5 s deadline and a 1 s liveliness lease: subscriptions may request either, or longer.
        q = qos.SETPOINT.replace(deadline=0.5, liveliness_lease_duration=1.0)
        pub = node.create_publisher(Setpoint, "setpoint", q)
        seq = 0

        def tick() -> None:
            nonlocal seq
            pub.publish(Setpoint(Header.now(seq=seq), x=0.1 * seq, y=1.0, z=-2.0))
            seq += 1

        node.create_timer(1.0 / rate, tick)
        node.spin()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="talker", description=__doc__)
    add_session_arguments(parser)
    parser.add_argument("--ns", default="demo", help="namespace of the example's node")
    parser.add_argument("--rate", type=float, default=10.0, help="setpoints per second")
    args = parser.parse_args()
    main(session_config_from_args(args), args.ns, args.rate)
