"""``zenoh-robot launch FILE.yaml [NAME:=VALUE ...]``: run a launch file (see zenoh_robot.tools.launch)."""
from __future__ import annotations

import argparse
import shlex

from ..launch import LaunchError, LaunchRunner, load_launch, parse_launch_args
from .main import CliError, Parser


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("launch", help="start a set of processes from a YAML launch file")
    p.add_argument("file", help="launch file (YAML)")
    p.add_argument("launch_args", nargs="*", metavar="NAME:=VALUE", help="launch arguments ($(arg NAME))")
    p.add_argument("--duration", type=float, help="stop everything after this many seconds")
    p.add_argument("--show", action="store_true", help="print the resolved commands and exit")
    p.add_argument("--sigint-timeout", type=float, default=5.0,
                   help="seconds between SIGINT and SIGTERM when stopping (default 5)")
    p.add_argument("--sigterm-timeout", type=float, default=3.0,
                   help="seconds between SIGTERM and SIGKILL when stopping (default 3)")
    p.set_defaults(func=run)
    # `launch demo.yaml --show duration:=20`: NAME:=VALUE after an option is still an argument.
    if isinstance(p, Parser):   # only the CLI's own parser knows intermixed
        p.intermixed = "launch_args"


def run(args: argparse.Namespace) -> int:
    try:
        description = load_launch(args.file, parse_launch_args(args.launch_args))
    except LaunchError as exc:
        raise CliError(str(exc)) from None
    if args.show:
        for spec in description.processes:
            flags = [f for f, on in (("required", spec.required), ("respawn", spec.respawn)) if on]
            delay = f" after {spec.delay:g} s" if spec.delay else ""
            print(f"{spec.name} [{', '.join(flags) or 'optional'}]{delay}: {shlex.join(spec.argv)}")
        return 0
    if args.duration is not None and not args.duration > 0:
        raise CliError(f"--duration must be > 0 seconds, got {args.duration:g}")
    runner = LaunchRunner(description, sigint_timeout=args.sigint_timeout, sigterm_timeout=args.sigterm_timeout)
    return runner.run(duration=args.duration)
