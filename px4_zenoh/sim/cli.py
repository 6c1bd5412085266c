"""``python -m px4_zenoh.sim --connect tcp/127.0.0.1:7447``: one simulated PX4 (zenoh build) as a process."""
from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from px4_link.sim.cli import _kv

from .px4_table import RATE_SETS
from .simulator import ZenohSimulator

DESCRIPTION = ("PX4 SITL stand-in speaking PX4's Zenoh protocol: a Zenoh client of the router at --connect "
               "(retrying every 5 s, as PX4 does), publishing /fmu/out/* and obeying /fmu/in/*.")


# One log format for every program of the project (the CLI, companion, GCS and both simulators): a
# log collector parses them all alike; tests/tools/test_log_format.py holds them to it.
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m px4_zenoh.sim", description=DESCRIPTION)
    p.add_argument("--connect", default="tcp/127.0.0.1:7447", help="router endpoint (PX4's default)")
    p.add_argument("--sysid", type=int, default=1, help="system id (MAV_SYS_ID, default 1)")
    p.add_argument("--domain", type=int, default=0, help="ZENOH_DOMAIN_ID (default 0)")
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: run until killed)")
    p.add_argument("--rates", choices=tuple(RATE_SETS), default="px4",
                   help="px4: PX4 SITL's publication rates (default); lean: fast topics slowed for small machines")
    p.add_argument("--param", type=_kv, action="append", default=[], metavar="NAME=VALUE",
                   help="set a PX4 parameter at boot, e.g. COM_OF_LOSS_T=2 (repeatable)")
    p.add_argument("--px4-msgs", type=Path, default=None, help="a PX4 tree's msg/ (default: the bundled types)")
    p.add_argument("--seed", type=int, default=None, help="noise seed")
    p.add_argument("--log-level", default="INFO")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format=LOG_FORMAT)
    sim = ZenohSimulator(args.connect, args.sysid, args.domain, rates=args.rates, params=dict(args.param),
                         msg_dir=args.px4_msgs, seed=args.seed)
    signal.signal(signal.SIGTERM, lambda *_: sim.stop())
    print(f"px4 zenoh sim {args.sysid}: client of {args.connect}; left out (types not bundled): "
          f"{' '.join(t.name for t in sim.left_out)}", file=sys.stderr, flush=True)
    try:
        sim.run_forever(args.duration)
    except KeyboardInterrupt:
        sim.stop()
    return 1 if sim.internal_errors else 0
