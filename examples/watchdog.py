"""Watch a setpoint stream the ROS 2 way: deadline, liveliness and incompatible-QoS events.

Run `python examples/talker.py` beside it, then stop or kill the talker: the deadline and
liveliness events say so. `zenoh-robot stats` in a third terminal shows this node's
statistics for the stream.
"""
import argparse

from zenoh_robot import Node, SubscriptionEventCallbacks, TopicStatisticsOptions, qos
from zenoh_robot.msgs import Setpoint

parser = argparse.ArgumentParser(description=__doc__)
parser.add_argument("--ns", default="demo")
parser.add_argument("--deadline", type=float, default=1.0,
                    help="seconds without a setpoint before an event (>= the talker's offered 0.5, or incompatible)")
args = parser.parse_args()

events = SubscriptionEventCallbacks(
    deadline=lambda s: print(f"deadline missed: {s.total_count} in all (+{s.total_count_change})"),
    liveliness=lambda s: print(f"publishers alive: {s.alive_count}, not alive: {s.not_alive_count}"),
    incompatible_qos=lambda s: print(f"a publisher was refused: {s.reason}"),
    message_lost=lambda s: print(f"lost {s.total_count_change} setpoints ({s.total_count} in all)"),
    matched=lambda s: print(f"matched publishers: {s.current_count}"),
)

with Node("watchdog", namespace=args.ns) as node:
    requested = qos.SETPOINT.replace(depth=10, deadline=args.deadline, liveliness_lease_duration=2.0)
    node.create_subscription(Setpoint, "setpoint", lambda msg: None, requested,
                             event_callbacks=events, topic_statistics=TopicStatisticsOptions(window=1.0))
    node.spin()
