"""``zenoh-robot foxglove [--port 8765]``: every topic, live, in Foxglove / Lichtblick (needs the ``logs`` extra)."""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from zenoh_robot.session_args import add_session_arguments

from .common import cli_node, quiet_exit
from .main import CliError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("foxglove", help="serve every topic live to Foxglove (WebSocket protocol; --ros2: "
                                        "ROS 2 topics as cdr channels Foxglove decodes)")
    add_session_arguments(p)
    p.add_argument("topics", nargs="*", metavar="TOPIC", help="only these topics (default: all, as they appear)")
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (0: any free one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default loopback: the bridge exposes every topic)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=run)


@quiet_exit
def run(args: argparse.Namespace) -> int:
    try:
        from zenoh_robot.tools.foxglove_bridge import FoxgloveBridge
    except ImportError as exc:
        raise CliError(f"needs foxglove-sdk: pip install 'zenoh-robot[logs]' ({exc})") from None
    if not 0 <= args.port <= 65535:
        raise CliError(f"--port must be 0..65535, got {args.port}")
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with cli_node("foxglove", args) as node:
        try:
            bridge = FoxgloveBridge(node, args.topics or None, host=args.host, port=args.port)
        except RuntimeError as exc:   # foxglove-sdk reports a busy port this way
            raise CliError(f"cannot serve on {args.host}:{args.port}: {exc}") from None
        try:
            bridge.start()
            print(f"foxglove bridge on {bridge.url} (open it in Foxglove: {bridge.app_url()})", flush=True)
            end = None if args.duration is None else time.monotonic() + args.duration
            while not stop.is_set():
                left = 0.5 if end is None else min(0.5, end - time.monotonic())
                if left <= 0:
                    break
                node.spin_until(stop.is_set, left)    # the bridge's subscriptions deliver on the executor
        except KeyboardInterrupt:
            pass
        finally:
            bridge.close()
    c = bridge.counters
    ros2 = f", {c.cdr} ROS 2 (cdr)" if bridge.node.wire.name == "ros2" else ""
    print(f"foxglove bridge: {c.forwarded} messages{ros2}, {c.views} views, {bridge.tap_counters.dropped} dropped",
          file=sys.stderr, flush=True)
    return 0
