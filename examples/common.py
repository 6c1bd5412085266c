"""Session flags shared by every example, written once (as zenoh-python's examples do)."""
from __future__ import annotations

import argparse

from zenoh_robot import SessionConfig


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("Zenoh session")
    group.add_argument("--mode", "-m", choices=("peer", "client", "router"), default="peer")
    group.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT",
                       help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    group.add_argument("--listen", "-l", action="append", default=[], metavar="ENDPOINT",
                       help="endpoint to listen on (repeatable)")
    group.add_argument("--zenoh", metavar="FILE", help="a Zenoh JSON5 config file (overrides the flags above)")
    group.add_argument("--ns", default="demo", help="namespace of the example's node")


def config_from_args(args: argparse.Namespace) -> SessionConfig | str:
    if args.zenoh:
        return str(args.zenoh)
    kw: dict[str, object] = {"mode": args.mode, "connect": list(args.connect)}
    if args.listen:
        kw["listen"] = list(args.listen)
    return SessionConfig(**kw)  # type: ignore[arg-type]
