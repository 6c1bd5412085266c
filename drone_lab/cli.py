"""``zenoh-robot demo | experiment | swarm``: the lab's subcommands, registered by entry point."""
from __future__ import annotations

import argparse

from . import demo, experiment_cli, swarm_cli


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    for module in (demo, experiment_cli, swarm_cli):
        module.register(sub)
