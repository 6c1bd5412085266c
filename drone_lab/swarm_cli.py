"""``zenoh-robot swarm``: the scaling sweep (one GCS, N drones that fly, peer and router) and swarm launch files."""
from __future__ import annotations

import argparse
from pathlib import Path


def _ints(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated drone counts, got {text!r}") from None
    if not values or any(not 1 <= v <= 250 for v in values):
        raise argparse.ArgumentTypeError("drone counts are 1..250")
    return values


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("swarm", help="scaling sweep: one GCS and N drones with simulators, peer and via a router")
    p.add_argument("--drones", type=_ints, default=[1, 2, 5, 10], help="drone counts (default 1,2,5,10)")
    p.add_argument("--modes", default="peer,router", help="peer, router or both (default peer,router)")
    p.add_argument("--camera", choices=("on", "off", "both"), default="on")
    p.add_argument("--duration", type=float, default=15.0,
                   help="measured seconds per cell: the pattern's flight (default 15)")
    p.add_argument("--warmup", type=float, default=8.0, help="--hover: seconds before measuring (default 8)")
    p.add_argument("--runs", type=int, default=1, help="runs per cell (the report gives median and range; default 1)")
    p.add_argument("--hover", action="store_true",
                   help="do not fly: the GCS streams hover setpoints that the grounded drones ignore (the sweep "
                        "before issue #29); default: every drone arms, flies the pattern in formation and lands")
    p.add_argument("--pattern", default="square", help="the formation's pattern (default square)")
    p.add_argument("--formation", default="grid", choices=("line", "grid"), help="slots (default grid)")
    p.add_argument("--spacing", type=float, default=5.0, help="m between slots (default 5)")
    p.add_argument("--size", type=float, default=4.0, help="pattern size, m (default 4)")
    p.add_argument("--sensor-rate", type=float, default=None, metavar="HZ",
                   help="SensorCombined rate the GCS asks of each drone (default 50, the swarm launch files'; "
                        "0: not asked, the drone's own 200 Hz)")
    p.add_argument("--camera-rate", type=float, default=None, metavar="FPS",
                   help="camera rate the GCS asks of each drone (default 15; 0: not asked, the drone's own 30)")
    p.add_argument("--downlink", choices=("swarm", "default", "both"), default="swarm",
                   help="swarm: the rates above; default: none asked (the drones' own); both: a cell of each")
    p.add_argument("--out", type=Path, default=Path("results/swarm"))
    p.add_argument("--report-only", action="store_true",
                   help="rebuild every result from the cells' raw records under --out (runner.json and the "
                        "processes' records), then redraw the tables and figure")
    p.add_argument("--launch", type=int, metavar="N",
                   help="print a launch file for a router, N companions with simulators and a GCS, and exit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drone_lab.experiment.swarm import (
        SWARM_CAMERA_FPS,
        SWARM_SENSOR_HZ,
        SwarmCell,
        load_results,
        reanalyse,
        run_sweep,
        swarm_launch,
    )
    from drone_lab.experiment.swarm_report import write_report
    from zenoh_robot.tools.cli.main import CliError

    if args.launch is not None:
        try:
            print(swarm_launch(args.launch), end="")
        except ValueError as exc:
            raise CliError(str(exc)) from None
        return 0
    out: Path = args.out
    if args.report_only:
        # Cells with raw records are analysed again; older results (no runner.json) are read as recorded.
        results = reanalyse(out) if any(out.glob("*/runner.json")) else load_results(out / "results.jsonl")
        if not results:
            raise CliError(f"no results in {out / 'results.jsonl'}")
    else:
        modes = [m for m in args.modes.split(",") if m]
        bad = [m for m in modes if m not in ("peer", "router")]
        if bad or not modes:
            raise CliError(f"--modes: peer and/or router, got {args.modes!r}")
        cams = {"on": [True], "off": [False], "both": [True, False]}[args.camera]
        sensor = SWARM_SENSOR_HZ if args.sensor_rate is None else args.sensor_rate
        camera = SWARM_CAMERA_FPS if args.camera_rate is None else args.camera_rate
        if sensor < 0 or camera < 0:
            raise CliError("--sensor-rate/--camera-rate: >= 0 (0: not asked)")
        swarm_rates: tuple[float | None, float | None] = (sensor or None, camera or None)
        choices: dict[str, list[tuple[float | None, float | None]]] = {
            "swarm": [swarm_rates], "default": [(None, None)], "both": [(None, None), swarm_rates]}
        downlinks = choices[args.downlink]
        if args.runs < 1:
            raise CliError("--runs: at least 1")
        from gcs.patterns import PATTERNS
        if args.pattern not in PATTERNS:
            raise CliError(f"--pattern: one of {', '.join(PATTERNS)}")
        fly = not args.hover
        cells = [SwarmCell(n, m, c, args.duration, args.warmup, sensor_rate=s, camera_rate=f, fly=fly,
                           pattern=args.pattern, formation=args.formation, spacing=args.spacing, size=args.size,
                           run=r + 1)
                 for r in range(args.runs) for n in args.drones for s, f in downlinks for m in modes for c in cams]
        # A flying cell: start-up, pre-arm checks, climb and landing (~35 s at a few drones, more when loaded).
        per_cell = args.duration + (35 if fly else args.warmup + 8)
        print(f"swarm: {len(cells)} cells, about {len(cells) * per_cell / 60:.0f} min; results in {out}", flush=True)
        run_sweep(out, cells, say=lambda s: print(s, flush=True))
        results = load_results(out / "results.jsonl")
    files = write_report(results, out)
    print((out / "results.md").read_text())
    for name, path in files.items():
        print(f"{name}: {path}")
    return 0
