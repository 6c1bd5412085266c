"""Command line for the simulator: ``python -m px4_link.sim --sysid 2 --port 14581``."""
from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Sequence

from .base import DEFAULT_HOME
from .faults import parse_ekf_reset, parse_estimate_loss, parse_low_battery
from .protocol import DEFAULT_RATES_HZ
from .simulator import Simulator

# One log format for every program of the project (the CLI, companion, GCS and both simulators): a
# log collector parses them all alike; tests/tools/test_log_format.py holds them to it.
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def _kv(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name.strip().upper(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"value of {name} is not a number: {value!r}") from None


def _home(text: str) -> tuple[float, float, float]:
    try:
        lat, lon, alt = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("expected LAT,LON,ALT") from None
    return lat, lon, alt


DESCRIPTION = ("PX4-faithful MAVLink quadrotor simulator. Like PX4 SITL's offboard link it "
               "sends from --port to --target-host:--target-port (14580 -> 14540).")


def build_parser(p: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    p = p or argparse.ArgumentParser(prog="python -m px4_link.sim", description=DESCRIPTION)
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--compid", type=int, default=1, help="MAVLink component id (default 1)")
    p.add_argument("--port", type=int, default=14580, help="our UDP port (default 14580, 0 = any)")
    p.add_argument("--bind", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument("--target-host", default="127.0.0.1", help="where to send (default 127.0.0.1)")
    p.add_argument("--target-port", type=int, default=14540, help="where to send (default 14540)")
    p.add_argument("--param", type=_kv, action="append", default=[], metavar="NAME=VALUE",
                   help="set a PX4 parameter at boot, e.g. COM_OBL_RC_ACT=5 (repeatable)")
    p.add_argument("--rate", type=_kv, action="append", default=[], metavar="MSG=HZ",
                   help="telemetry rate, e.g. HIGHRES_IMU=200 (repeatable; 0 disables). "
                        f"Streams: {', '.join(DEFAULT_RATES_HZ)}")
    p.add_argument("--home", type=_home, default=DEFAULT_HOME, metavar="LAT,LON,ALT",
                   help="home position (default PX4 SITL's Zurich)")
    p.add_argument("--physics-hz", type=float, default=100.0, help="physics rate (default 100)")
    p.add_argument("--seed", type=int, default=None, help="noise seed")
    p.add_argument("--estimate-loss", type=parse_estimate_loss, action="append", default=[],
                   metavar="AT:DURATION", help="fault: the position estimate is lost AT s after start "
                   "for DURATION s (repeatable)")
    p.add_argument("--ekf-reset", type=parse_ekf_reset, action="append", default=[],
                   metavar="AT:NORTH[,EAST[,DOWN]]", help="fault: an estimator reset AT s after start "
                   "makes the local position jump by the given metres (repeatable)")
    p.add_argument("--low-battery", type=parse_low_battery, action="append", default=[],
                   metavar="AT:LEVEL", help="fault: the battery reads LEVEL (0..1) from AT s after start "
                   "(repeatable)")
    p.add_argument("--log-level", default="WARNING")
    return p


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """``zenoh-robot sim``: the same options (a plugin hook; this module imports no Zenoh)."""
    p = build_parser(sub.add_parser("sim", help="the built-in PX4-faithful MAVLink simulator",
                                    description=DESCRIPTION))
    p.set_defaults(func=run)


def main(argv: Sequence[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=args.log_level.upper(), format=LOG_FORMAT)
    try:
        sim = Simulator(args.sysid, compid=args.compid, port=args.port, bind_host=args.bind,
                        target_host=args.target_host, target_port=args.target_port,
                        params=dict(args.param), rates=dict(args.rate), home=args.home,
                        physics_hz=args.physics_hz, seed=args.seed,
                        faults=[*args.estimate_loss, *args.ekf_reset, *args.low_battery])
    except KeyError as e:
        print(f"unknown parameter or stream: {e}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: sim.stop())
    sim.start()
    print(f"px4_link.sim sysid={sim.sysid} port={sim.port} -> "
          f"{sim.target[0]}:{sim.target[1]}", flush=True)
    try:
        sim.run_forever()
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop()
    return 0
