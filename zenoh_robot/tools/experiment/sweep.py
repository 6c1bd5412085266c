"""The sweep: every (start mode, profile, loss) cell, appended to results as it finishes.

An interrupted sweep keeps every finished cell (``results.jsonl`` is appended one
line per cell); ``--resume`` skips cells already there. Figures and the markdown
table are drawn from whatever the file holds.
"""
from __future__ import annotations

import json
import time
from collections.abc import Iterable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from .cell import CellSpec, run_cell

LOSSES = (0, 1, 2, 5, 10, 20, 30, 40, 50, 60, 70, 80, 90)
PROFILES = ("reliable", "best_effort", "resilient")


def _key(r: dict[str, Any]) -> tuple[str, str, float]:
    return r["start"], r["profile"], float(r["loss"])   # profile: the cell's label (profile@transport)


def load_results(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        if line.strip():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue   # a line cut by an interrupted write
    return out


def run_sweep(out_dir: Path, cells: Iterable[CellSpec], resume: bool = False,
              console: Console | None = None) -> list[dict[str, Any]]:
    console = console or Console()
    out_dir.mkdir(parents=True, exist_ok=True)
    results_path = out_dir / "results.jsonl"
    done = {_key(r) for r in load_results(results_path)} if resume else set()
    if not resume and results_path.exists():
        results_path.rename(results_path.with_suffix(f".{int(time.time())}.jsonl"))
    todo = [c for c in cells if (c.start, c.label, float(c.loss)) not in done]
    columns = (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total} cells"),
               TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("sweep", total=len(todo))
        for spec in todo:
            progress.update(task, description=f"{spec.label:11s} {spec.loss:4.0f}% loss ({spec.start})")
            workdir = out_dir / "cells" / f"{spec.start}-{spec.label}-{spec.loss:g}"
            try:
                result = run_cell(spec, workdir)
            except Exception as exc:   # one broken cell must not lose the sweep
                result = {**asdict(spec), "profile": spec.label, "error": f"{type(exc).__name__}: {exc}", "topics": {}}
            with results_path.open("a") as f:
                f.write(json.dumps(result) + "\n")
            progress.console.print(one_line(result))
            progress.advance(task)
    return load_results(results_path)


def one_line(r: dict[str, Any]) -> str:
    if r.get("error"):
        return f"{r['profile']:11s} {r['loss']:4.0f}%: ERROR {r['error']}"
    t = r["topics"]

    def f(topic: str) -> str:
        s = t.get(topic, {})
        return f"{topic} {s.get('delivered_pct', float('nan')):5.1f}% {s.get('age_avg_ms', float('nan')):7.1f}ms"
    return (f"{r['profile']:11s} {r['loss']:4.0f}% ({r['start']}): {f('setpoint')} | {f('sensor')} | "
            f"{f('image')} | offboard {'kept' if r.get('offboard_kept') else 'LOST'}")
