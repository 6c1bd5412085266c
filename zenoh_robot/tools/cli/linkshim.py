"""``zenoh-robot linkshim``: a UDP tunnel that repeats datagrams across a lossy hop (docs/results/linkshim.md).

Drone end: ``zenoh-robot linkshim drone --listen 127.0.0.1:7448 --peer GROUND:7449`` and the companion's
Zenoh connects to ``udp/127.0.0.1:7448``. Ground end: ``zenoh-robot linkshim ground --listen 0.0.0.0:7449
--target 127.0.0.1:7447`` (the router's or GCS's UDP endpoint).
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import threading


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("linkshim", help="repeat Zenoh's UDP datagrams across a lossy link (handshake from 90 %% loss)")
    p.add_argument("role", choices=("drone", "ground"))
    p.add_argument("--listen", required=True, help="host:port: local for the drone end, on the link for the ground end")
    p.add_argument("--peer", help="drone end: the ground end's host:port")
    p.add_argument("--target", help="ground end: the router's/GCS's UDP host:port")
    p.add_argument("--k-warm", type=int, default=32, help="copies while a flow is young, quiet or unmeasured")
    p.add_argument("--k-max", type=int, default=16, help="most copies of a small datagram once loss is measured")
    p.add_argument("--k-big", type=int, default=2, help="most copies of a big datagram once loss is measured")
    p.add_argument("--budget-kBps", type=float, default=4000.0, help="bytes/s of extra copies, in kB/s")
    p.add_argument("--stats", type=float, default=0.0, help="print counters as JSON every N s (0: on exit only)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..linkshim import LinkShim, ShimConfig, parse_addr
    from .main import CliError

    if args.role == "drone" and not args.peer:
        raise CliError("the drone end needs --peer (the ground end's host:port)")
    if args.role == "ground" and not args.target:
        raise CliError("the ground end needs --target (the router's UDP host:port)")
    cfg = ShimConfig(k_warm=args.k_warm, k_small_max=args.k_max, k_big_max=args.k_big,
                     budget_Bps=args.budget_kBps * 1000)
    shim = LinkShim(args.role, parse_addr(args.listen), peer=parse_addr(args.peer) if args.peer else None,
                    target=parse_addr(args.target) if args.target else None, cfg=cfg).start()
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    print(f"linkshim {args.role} listening on {shim.address[0]}:{shim.address[1]}", flush=True)
    try:
        while not done.wait(args.stats or 3600):
            if args.stats:
                print(json.dumps(shim.stats()), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        shim.stop()
        print(json.dumps(shim.stats()), file=sys.stdout, flush=True)
    return 0


if __name__ == "__main__":
    # `python -m zenoh_robot.tools.cli.linkshim drone ...`: this subcommand alone, without loading the others
    # (and the apps' plugins), so a shim starts in a fraction of a second on a loaded machine.
    from zenoh_robot.tools.cli.main import run_single
    sys.exit(run_single(register, "linkshim", "linkshim"))
