"""Receive setpoints and print each one's age (source stamp to arrival) and period."""
from __future__ import annotations

import argparse
import time

from common import add_config_arguments, config_from_args

from zenoh_robot import MessageInfo, Node, qos
from zenoh_robot.msgs import Setpoint


def main(conf: object, ns: str) -> None:
    last: float | None = None

    def on_setpoint(msg: Setpoint, info: MessageInfo) -> None:
        nonlocal last
        now = time.monotonic()
        period = f"{(now - last) * 1000:6.1f} ms" if last else "     -   "
        last = now
        print(f"seq {info.seq:5d}  x={msg.x:6.2f}  age {info.age_ms:6.2f} ms  period {period}", flush=True)

    with Node("listener", namespace=ns, config=conf) as node:  # type: ignore[arg-type]
        node.create_subscription(Setpoint, "setpoint", on_setpoint, qos.SETPOINT)
        node.spin()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="listener", description=__doc__)
    add_config_arguments(parser)
    args = parser.parse_args()
    main(config_from_args(args), args.ns)
