"""Watch a setpoint stream the ROS 2 way: deadline, liveliness and incompatible-QoS events.

Run `python examples/talker.py` beside it, then stop or kill the talker: the deadline and
liveliness events say so. `zenoh-robot stats` in a third terminal shows this node's
statistics for the stream.
"""
from __future__ import annotations

import argparse

from zenoh_robot import Node, SessionConfig, SubscriptionEventCallbacks, TopicStatisticsOptions, qos
from zenoh_robot.session_args import add_session_arguments, session_config_from_args


def main(conf: SessionConfig, ns: str, deadline: float) -> None:
    from zenoh_robot.msgs import Setpoint

    events = SubscriptionEventCallbacks(
        deadline=lambda s: print(f"deadline missed: {s.total_count} in all (+{s.total_count_change})"),
        liveliness=lambda s: print(f"publishers alive: {s.alive_count}, not alive: {s.not_alive_count}"),
        incompatible_qos=lambda s: print(f"a publisher was refused: {s.reason}"),
        message_lost=lambda s: print(f"lost {s.total_count_change} setpoints ({s.total_count} in all)"),
        matched=lambda s: print(f"matched publishers: {s.current_count}"),
    )
    with Node("watchdog", namespace=ns, config=conf) as node:
        requested = qos.SETPOINT.replace(depth=10, deadline=deadline, liveliness_lease_duration=2.0)
        node.create_subscription(Setpoint, "setpoint", lambda msg: None, requested,
                                 event_callbacks=events, topic_statistics=TopicStatisticsOptions(window=1.0))
        node.spin()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="watchdog", description=__doc__)
    add_session_arguments(parser)
    parser.add_argument("--ns", default="demo", help="namespace of the example's node")
    parser.add_argument("--deadline", type=float, default=1.0,
                        help="seconds without a setpoint before an event "
                             "(>= the talker's offered 0.5, or incompatible)")
    args = parser.parse_args()
    main(session_config_from_args(args), args.ns, args.deadline)
