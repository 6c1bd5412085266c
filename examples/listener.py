"""Receive setpoints and print each one's age (source stamp to arrival) and period."""
import argparse
import time

from zenoh_robot import MessageInfo, Node, qos
from zenoh_robot.msgs import Setpoint

parser = argparse.ArgumentParser(description=__doc__)
parser.add_argument("--ns", default="demo")
args = parser.parse_args()

last = None


def on_setpoint(msg: Setpoint, info: MessageInfo) -> None:
    global last
    now = time.monotonic()
    period = f"{(now - last) * 1000:6.1f} ms" if last else "     -   "
    last = now
    print(f"seq {info.seq:5d}  x={msg.x:6.2f}  age {info.age_ms:6.2f} ms  period {period}", flush=True)


with Node("listener", namespace=args.ns) as node:
    node.create_subscription(Setpoint, "setpoint", on_setpoint, qos.SETPOINT)
    node.spin()
