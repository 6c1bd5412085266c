"""``zenoh-robot bag record|info|play``: flight logs in MCAP (ros2 bag's shape; needs the ``logs`` extra)."""
from __future__ import annotations

import argparse
import re
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from zenoh_robot.session_args import add_session_arguments

from .common import cli_node, quiet_exit
from .main import CliError

if TYPE_CHECKING:
    pass


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bag", help="record, inspect and replay flight logs (MCAP, opens in Foxglove)")
    add_session_arguments(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)

    r = ops.add_parser("record", help="record topics to an MCAP file")
    add_session_arguments(r)
    r.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (absolute names)")
    r.add_argument("-a", "--all", action="store_true", help="every topic, including ones that appear later")
    r.add_argument("-o", "--output", required=True, help="the .mcap file to write")
    r.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    r.add_argument("--no-views", action="store_true", help="no foxglove.* views (poses, fixes, images)")
    r.add_argument("--no-raw", action="store_true", help="no raw wire bytes (the file cannot be replayed)")
    r.add_argument("--slice-json", action=argparse.BooleanOptionalAction, default=False,
                   help="also image slices as JSON (base64 JPEG, the bulk of a file); default: no, Foxglove "
                        "shows the reassembled <topic>/image and replay uses the raw bytes")
    r.add_argument("-x", "--exclude", metavar="REGEX",
                   help="leave out topics this regular expression matches (searched in the name)")
    r.set_defaults(func=_record)

    i = ops.add_parser("info", help="topics, types, counts and rates of a recording")
    i.add_argument("file")
    i.add_argument("--raw", action="store_true", help="also list the raw wire channels")
    i.add_argument("--json", action="store_true", help="print JSON")
    i.set_defaults(func=_info)

    pl = ops.add_parser("play", help="republish a recording with its timing, types and QoS (ROS 2 cdr channels "
                                     "on the ROS 2 wire: --ros-domain-id, else ROS_DOMAIN_ID or 0)")
    add_session_arguments(pl)
    pl.add_argument("file")
    pl.add_argument("topics", nargs="*", metavar="TOPIC", help="only these topics")
    pl.add_argument("--rate", type=float, default=1.0, help="speed factor (2 = twice as fast)")
    pl.add_argument("--loop", action="store_true",
                    help="start again at the end (each pass as new publisher ids: subscriptions take it as new)")
    pl.add_argument("--passes", type=int, metavar="N", help="with --loop: stop after N passes")
    pl.add_argument("--restamp", action="store_true",
                    help="source stamps = now (for consumers checking age/lifespan); default: bit-exact")
    pl.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    pl.set_defaults(func=_play)


def _need_logs_extra() -> None:
    try:
        import mcap  # noqa: F401
    except ImportError:
        raise CliError("needs the mcap package: pip install 'zenoh-robot[logs]'") from None


def _stop_on_sigterm(stop: threading.Event) -> None:
    # SIGINT too: a parent (demo, launch) stopping us with it must get a finished file, even when
    # the shell started us with SIGINT ignored.
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())


@quiet_exit
def _record(args: argparse.Namespace) -> int:
    _need_logs_extra()
    from zenoh_robot.tools.bag.record import BagRecorder

    if not args.all and not args.topics:
        raise CliError("name topics to record, or -a for all")
    if args.duration is not None and not args.duration > 0:
        raise CliError(f"--duration must be > 0 seconds, got {args.duration:g}")
    if args.exclude:
        try:
            re.compile(args.exclude)
        except re.error as exc:
            raise CliError(f"--exclude {args.exclude!r}: {exc}") from None
    stop = threading.Event()
    _stop_on_sigterm(stop)
    with cli_node("bag", args) as node:
        rec = BagRecorder(node, args.output, None if args.all else args.topics, views=not args.no_views,
                          raw=not args.no_raw, slice_json=args.slice_json, exclude=args.exclude)
        try:
            rec.start()
            print(f"recording to {args.output} (Ctrl-C to stop)", file=sys.stderr, flush=True)
            end = None if args.duration is None else time.monotonic() + args.duration
            while not stop.is_set():
                left = 0.5 if end is None else min(0.5, end - time.monotonic())
                if left <= 0:
                    break
                # The recorder's subscriptions deliver on this node's executor.
                node.spin_until(stop.is_set, left)
        except KeyboardInterrupt:
            pass
        finally:
            rec.close()
    import resource
    c, t = rec.counters, rec.tap_counters
    cpu = resource.getrusage(resource.RUSAGE_SELF)
    size = Path(args.output).stat().st_size
    ros2 = f", {c.cdr_written} ROS 2 (cdr)" if c.cdr_written or c.untyped or c.no_definition else ""
    print(f"wrote {args.output}: {size / 1e6:.2f} MB, {c.written} messages on {len(c.per_topic)} topics "
          f"({c.raw_written} raw{ros2}, {c.views_written} views, {t.dropped + t.sub_dropped} dropped, "
          f"{t.sub_malformed} malformed); "
          f"cpu {cpu.ru_utime + cpu.ru_stime:.1f} s, max rss {cpu.ru_maxrss / 1024:.0f} MB",
          file=sys.stderr, flush=True)
    return 0


def _info(args: argparse.Namespace) -> int:
    _need_logs_extra()
    from zenoh_robot.tools.bag.info import NotMcapError, dumps, format_info, read_info

    try:
        info = read_info(args.file)
    except NotMcapError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"{args.file}: {exc.strerror or exc}") from None
    print(dumps(info) if args.json else format_info(info, show_raw=args.raw))
    return 0


@quiet_exit
def _play(args: argparse.Namespace) -> int:
    _need_logs_extra()
    from zenoh_robot.tools.bag.info import NotMcapError, check_mcap
    from zenoh_robot.tools.bag.play import BagPlayer

    if not args.rate > 0:
        raise CliError(f"--rate must be > 0, got {args.rate:g}")
    try:   # before the session opens: a wrong file is known at once
        check_mcap(args.file)
    except NotMcapError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"{args.file}: {exc.strerror or exc}") from None
    with cli_node("bag_play", args) as node:
        try:
            player = BagPlayer(node, args.file, args.topics or None, rate=args.rate, loop=args.loop,
                               restamp=args.restamp, passes=args.passes,
                               on_unplayable=lambda line: print(line, file=sys.stderr, flush=True))
        except ValueError as exc:
            raise CliError(str(exc)) from None
        stop = threading.Event()
        _stop_on_sigterm(stop)

        def stop_player() -> None:
            stop.wait()
            player.stop()
        threading.Thread(target=stop_player, daemon=True).start()
        try:
            c = player.play(args.duration)
        except OSError as exc:
            raise CliError(str(exc)) from None
        finally:
            player.close()
    ros2 = f", {c.ros2_published} of them ROS 2" if c.ros2_published else ""
    print(f"published {c.published} samples on {len(c.per_topic)} topics ({c.loops} loops{ros2})", file=sys.stderr)
    if c.unplayable and not c.published:
        raise CliError(f"nothing played: {len(c.unplayable)} channels cannot be played (above)")
    return 0
