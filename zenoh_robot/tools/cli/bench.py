"""``zenoh-robot bench``: framework vs raw zenoh-python, same run; ``--soak`` for memory growth."""
from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bench", help="latency, throughput and CPU against raw zenoh-python")
    p.add_argument("--quick", action="store_true", help="a tenth of the messages (a smoke run)")
    p.add_argument("--only", help="comma-separated payloads: setpoint,sensor,image,jpeg")
    p.add_argument("--soak", action="store_true", help="also a soak at 1 kHz measuring memory growth")
    p.add_argument("--soak-minutes", type=float, default=10.0)
    p.add_argument("--out", type=Path, default=Path("results/bench"))
    p.add_argument("--ros2", action="store_true",
                   help="the ROS 2 wire: CDR codec per type, and end to end beside the envelope, zenoh-ros2-sdk "
                        "and raw zenoh")
    p.add_argument("--reps", type=int, default=5, help="alternating framework/raw repetitions per cell (medians)")
    p.add_argument("--receive", choices=("callback", "channel"), help="the framework's receive path")
    p.add_argument("--express", action="store_true",
                   help="both sides publish with Zenoh's express (each sample sent at once, no batching), as the "
                        "setpoint, control and resilient profiles do")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from ..bench.report import markdown, table
    from ..bench.runner import plan, run_all, run_soak, to_json
    from .main import CliError

    if args.ros2:
        return _ros2(args)
    only = [p for p in (args.only or "").split(",") if p]
    cells = plan(args.quick, only)
    if not cells:
        raise CliError(f"no cells for --only {args.only!r} (payloads: setpoint, sensor, image, jpeg)")
    console = Console()
    with console.status("") as status:
        results = run_all(cells, lambda c: status.update(
            f"{c.payload} {c.kind} {c.rate:g} Hz x{c.count}: framework and raw zenoh-python, {args.reps} times"
            + (" (express)" if args.express else "")),
            reps=args.reps, receive=args.receive, express=args.express)
        soak = None
        if args.soak:
            status.update(f"soak: {args.soak_minutes:g} min at 1 kHz")
            soak = run_soak(args.soak_minutes)
    console.print(table(results, console.width))
    md = markdown(results, soak)
    if soak:
        console.print(md.split("\n\n")[-1])
    to_json(results, soak, args.out / "bench.json")
    (args.out / "bench.md").write_text(md + "\n")
    console.print(f"bench: {args.out / 'bench.json'}, {args.out / 'bench.md'}")
    return 0


def _ros2(args: argparse.Namespace) -> int:
    from rich.console import Console

    from ..bench.report import FULL_WIDTH, ros2_tables
    from ..bench.ros2 import codec_figures, end_to_end, markdown, write_json

    console = Console()
    with console.status("bench --ros2: codec per type") as status:
        codec = codec_figures()
        status.update(f"bench --ros2: latency, throughput and CPU; ros2, envelope, zenoh-ros2-sdk and raw "
                      f"zenoh-python alternating, {args.reps} times")
        e2e = end_to_end(args.quick, args.reps, args.receive)
    md = markdown(codec, e2e)
    if console.width >= FULL_WIDTH:
        console.print(md, markup=False, highlight=False, soft_wrap=True)   # the terminal wraps, rich adds no breaks
    else:
        for t in ros2_tables(codec, e2e):
            console.print(t)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ros2.md").write_text(md + "\n")
    write_json(args.out / "ros2.json", codec, e2e)
    console.print(f"bench: {args.out / 'ros2.json'}, {args.out / 'ros2.md'}")
    return 0
