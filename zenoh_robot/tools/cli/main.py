"""zenoh-robot: ROS 2-style nodes, QoS and tools over Zenoh, and the drone GCS/companion.

Each subcommand lives in its own module with ``register(sub)``, which adds a parser
and sets ``func(args) -> int``. Built-in ones are modules of this package; the
applications (gcs, companion, the PX4 simulator) plug in through the
``zenoh_robot.tools.cli`` entry-point group, so this package never imports them (nor MAVLink).
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Callable

from importlib.metadata import entry_points

SUBCOMMANDS = ["topic", "stats", "param", "service", "launch", "bench", "experiment", "demo", "keys", "router", "bag", "foxglove"]


class CliError(Exception):
    """An error to print as one line, exiting non-zero."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="zenoh-robot", description=(__doc__ or "").splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"zenoh_robot.tools.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"zenoh_robot.tools.cli.{name}":
                continue
            raise
        module.register(sub)
    for ep in sorted(entry_points(group="zenoh_robot.cli"), key=lambda e: e.name):
        try:
            ep.load()(sub)
        except (ImportError, AttributeError) as exc:   # one broken plugin must not take the CLI down
            print(f"zenoh-robot: subcommand {ep.name!r} unavailable: {exc}", file=sys.stderr)
    return parser


def main(argv: list[str] | None = None, parser: argparse.ArgumentParser | None = None) -> int:
    parser = parser or build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if getattr(args, "verbose", False) else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except CliError as exc:
        print(f"zenoh-robot {args.command}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    # Run as `python -m zenoh_robot.tools.cli.main`, this file is `__main__`, a second copy of the
    # module: subcommands raise the CliError of `zenoh_robot.tools.cli.main`, so call that copy's main.
    from zenoh_robot.tools.cli.main import main as _main
    sys.exit(_main())


def run_single(register: Callable[[argparse._SubParsersAction], None], command: str, prog: str,
               argv: list[str] | None = None) -> int:
    """Run one plugin subcommand as its own program (``python -m gcs`` == ``zenoh-robot gcs``)."""
    parser = argparse.ArgumentParser(prog=prog)
    sub = parser.add_subparsers(dest="command", required=True)
    register(sub)
    return main([command, *(sys.argv[1:] if argv is None else argv)], parser=parser)
