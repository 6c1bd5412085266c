"""``zenoh-robot experiment``: the thesis's lossy-link experiment, reproduced and extended."""
from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console


def _floats(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if any(not 0 <= v <= 100 for v in values):
        raise argparse.ArgumentTypeError("loss values are percentages 0..100")
    return values


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from drone_lab.experiment.sweep import LOSSES, PROFILES
    p = sub.add_parser("experiment", help="sweep packet loss between two network namespaces (needs root)")
    p.add_argument("--loss", type=_floats, default=list(LOSSES), help="loss %% values (default: the thesis's sweep)")
    p.add_argument("--profiles", default=",".join(PROFILES), help=f"comma-separated (default {','.join(PROFILES)})")
    p.add_argument("--start", choices=("after", "startup", "both"), default="after",
                   help="apply loss after set-up (the thesis), from start-up, or both")
    p.add_argument("--duration", type=float, default=30.0,
                   help="measured seconds per cell, flying the pattern through the loss (default 30: 300 setpoints "
                        "at 10 Hz, so none lost bounds the loss under 1 %% per run)")
    p.add_argument("--warmup", type=float, default=5.0,
                   help="seconds of the pattern flown before the window (default 5); the loss comes on then "
                        "with --start after")
    p.add_argument("--runs", type=int, default=3, help="runs per cell (default 3: the report gives median and range)")
    p.add_argument("--pattern", default="square", choices=("square", "circle", "line", "hover"),
                   help="the pattern the GCS's mission flies (default square)")
    p.add_argument("--transport", default="default",
                   help="comma-separated: default (each profile's own: multicast for resilient), unicast "
                        "(resilient over a UDP/TCP peer-to-peer session with fast open retries), router "
                        "(every profile through a Zenoh router in the GCS namespace, both apps its clients)")
    p.add_argument("--loss-model", default="uniform",
                   help="comma-separated: uniform (independent drops, the thesis) and/or bursty (a two-state "
                        "channel at the same mean: 95 %% fades of 100 ms - 2 s, mean --burst-mean)")
    p.add_argument("--burst-mean", type=float, default=0.3, help="mean fade of the bursty model, s (default 0.3)")
    p.add_argument("--out", type=Path, default=Path("results/experiment"))
    p.add_argument("--resume", action="store_true",
                   help="keep finished cells of an earlier run in --out (cells flagged invalid run again)")
    p.add_argument("--report-only", nargs="?", const=True, default=False, type=Path, metavar="DIR",
                   help="redraw every figure and table from the raw results in DIR (default --out)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drone_contract.streams import PROFILES as KNOWN
    from drone_lab.experiment.cell import CellSpec
    from drone_lab.experiment.netns import unavailable_reason
    from drone_lab.experiment.report import write_report
    from drone_lab.experiment.sweep import load_results, run_sweep
    from zenoh_robot.tools.cli.main import CliError

    console = Console()
    out: Path = args.report_only if isinstance(args.report_only, Path) else args.out
    if not args.report_only:
        reason = unavailable_reason()
        if reason:
            raise CliError(reason)
        profiles = [p for p in args.profiles.split(",") if p]
        unknown = [p for p in profiles if p not in KNOWN]
        if unknown:
            raise CliError(f"unknown profile(s) {unknown}; profiles: {', '.join(KNOWN)}")
        starts = ["after", "startup"] if args.start == "both" else [args.start]
        transports = [t for t in args.transport.split(",") if t]
        from drone_lab.experiment.cell import TRANSPORTS
        if any(t not in TRANSPORTS for t in transports):
            raise CliError(f"unknown transport in {transports}; transports: {', '.join(TRANSPORTS)}")
        from drone_lab.experiment.cell import LOSS_MODELS
        models = [m for m in args.loss_model.split(",") if m]
        if not models or any(m not in LOSS_MODELS for m in models):
            raise CliError(f"unknown loss model in {models}; loss models: {', '.join(LOSS_MODELS)}")
        if not 0.1 <= args.burst_mean <= 2.0:
            raise CliError(f"--burst-mean {args.burst_mean:g}: fades last 0.1-2 s")
        if args.runs < 1:
            raise CliError(f"--runs {args.runs}: at least 1")
        cells = [CellSpec(p, loss, s, args.duration, args.warmup, t, loss_model=m, burst_mean_s=args.burst_mean,
                          pattern=args.pattern, run=run)
                 for run in range(args.runs) for m in models for s in starts for p in profiles
                 for t in transports if t in ("default", "router") or p == "resilient" for loss in args.loss]
        # Each flight: start-up, arm and climb (~15 s), warm-up, window, tail, landing (~15 s).
        console.print(f"{len(cells)} flown cells of {args.duration:g} s ({args.runs} runs each): about "
                      f"{len(cells) * (args.duration + args.warmup + 35) / 60:.0f} min; results in {out}")
        results = run_sweep(out, cells, resume=args.resume, console=console)
    else:
        results = load_results(out / "results.jsonl", include_invalid=True)
        if not results:
            raise CliError(f"no results in {out / 'results.jsonl'}")
    files = write_report(results, out)
    console.print((out / "results.md").read_text())
    for name, path in files.items():
        console.print(f"{name}: {path}")
    return 0
