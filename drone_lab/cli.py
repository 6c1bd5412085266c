"""``zenoh-robot demo | experiment | swarm | lab``: the lab's subcommands, registered by entry point."""
from __future__ import annotations

import argparse

from . import demo, experiment_cli, px4_latency, swarm_cli


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    for module in (demo, experiment_cli, swarm_cli):
        module.register(sub)
    lab = sub.add_parser("lab", help="the lab's measurements: px4-latency")
    px4_latency.register(lab.add_subparsers(dest="lab_command", metavar="MEASUREMENT", required=True))
