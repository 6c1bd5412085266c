"""Receive setpoints and print each one's age (source stamp to arrival) and period."""
from __future__ import annotations

import argparse
import time

from zenoh_robot import MessageInfo, Node, SessionConfig, qos
from zenoh_robot.msgs import Setpoint
from zenoh_robot.session_args import add_session_arguments, session_config_from_args


def main(conf: SessionConfig, ns: str) -> None:
    last: float | None = None

    def on_setpoint(msg: Setpoint, info: MessageInfo) -> None:
        nonlocal last
        now = time.monotonic()
        period = f"{(now - last) * 1000:6.1f} ms" if last else "     -   "
        last = now
        print(f"seq {info.seq:5d}  x={msg.x:6.2f}  age {info.age_ms:6.2f} ms  period {period}", flush=True)

    with Node("listener", namespace=ns, config=conf) as node:
        node.create_subscription(Setpoint, "setpoint", on_setpoint, qos.SETPOINT)
        node.spin()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="listener", description=__doc__)
    add_session_arguments(parser)
    parser.add_argument("--ns", default="demo", help="namespace of the example's node")
    args = parser.parse_args()
    main(session_config_from_args(args), args.ns)
