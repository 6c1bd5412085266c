"""The sweep: every (start mode, profile, loss, run) cell, appended to results as it finishes.

An interrupted sweep keeps every finished cell (``results.jsonl`` is appended one
line per cell, its raw records under ``cells/``); ``--resume`` skips cells already there.
Figures and the markdown tables are drawn from whatever the file holds, invalid cells
listed with their reason.
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


def _key(r: dict[str, Any]) -> tuple[str, str, float, int]:
    # profile: the cell's label (profile@transport~loss model)
    return r["start"], r["profile"], float(r["loss"]), int(r.get("run", 0))


def cell_dir(spec: CellSpec) -> str:
    """A cell's directory under ``cells/`` (its raw records)."""
    return f"{spec.start}-{spec.label}-{spec.loss:g}-r{spec.run}"


def needs_rerun(r: dict[str, Any]) -> bool:
    """A cell that measured nothing about the link: its window missed the streams (``invalid``: the
    apps' start-up or exit inside it) or the harness broke. A session that never formed is a result."""
    return bool(r.get("invalid")) or (bool(r.get("error")) and not r.get("no_session"))


def load_results(path: Path, include_invalid: bool = False) -> list[dict[str, Any]]:
    """The cells in ``results.jsonl``, the latest line per cell (a rerun replaces an earlier line).

    Cells flagged ``invalid`` (and never measured validly since) are left out unless ``include_invalid``:
    the report lists them with their reason, never as figures; ``--resume`` runs them again. Harness
    errors stay in (the report lists them as errors)."""
    if not path.exists():
        return []
    latest: dict[tuple[str, str, float, int], dict[str, Any]] = {}
    for line in path.read_text().splitlines():
        if line.strip():
            try:
                r = json.loads(line)
                key = _key(r)
            except (ValueError, KeyError, TypeError):
                continue   # a line cut by an interrupted write
            if not r.get("invalid") or key not in latest or latest[key].get("invalid"):
                latest[key] = r   # a valid line is never replaced by a later invalid one
    return [r for r in latest.values() if include_invalid or not r.get("invalid")]


def run_sweep(out_dir: Path, cells: Iterable[CellSpec], resume: bool = False,
              console: Console | None = None) -> list[dict[str, Any]]:
    console = console or Console()
    out_dir.mkdir(parents=True, exist_ok=True)
    results_path = out_dir / "results.jsonl"
    done = {_key(r) for r in load_results(results_path) if not needs_rerun(r)} if resume else set()
    if not resume and results_path.exists():
        results_path.rename(results_path.with_suffix(f".{int(time.time())}.jsonl"))
    todo = [c for c in cells if (c.start, c.label, float(c.loss), c.run) not in done]
    columns = (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total} cells"),
               TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("sweep", total=len(todo))
        for spec in todo:
            progress.update(task, description=f"{spec.label:11s} {spec.loss:4.0f}% loss ({spec.start}) run {spec.run}")
            workdir = out_dir / "cells" / cell_dir(spec)
            try:
                result = run_cell(spec, workdir)
            except Exception as exc:   # one broken cell must not lose the sweep
                result = {**asdict(spec), "profile": spec.label, "error": f"{type(exc).__name__}: {exc}", "topics": {},
                          "cell_dir": cell_dir(spec)}
            result["cell_dir"] = cell_dir(spec)
            with results_path.open("a") as f:
                f.write(json.dumps(result) + "\n")
            progress.console.print(one_line(result))
            progress.advance(task)
    return load_results(results_path, include_invalid=True)


def one_line(r: dict[str, Any]) -> str:
    if r.get("error"):
        return f"{r['profile']:11s} {r['loss']:4.0f}% ({r['start']}): ERROR {r['error']}"
    if r.get("invalid"):
        return f"{r['profile']:11s} {r['loss']:4.0f}% ({r['start']}): INVALID (rerun with --resume) {r['invalid']}"
    t = r["topics"]
    fl = r.get("flight") or {}
    age = (fl.get("vehicle_target") or {}).get("age_max_ms")
    flown = (f" | OFFBOARD {100 * (fl.get('offboard_share_window') or 0):.0f}% failsafes {fl.get('failsafes')}"
             f" target age max {age if age is not None else '-'} ms"
             f" | mission {'ok' if fl.get('mission_ok') else 'FAILED'}") if fl else ""

    def f(topic: str) -> str:
        s = t.get(topic, {})
        return f"{topic} {s.get('delivered_pct', float('nan')):5.1f}% {s.get('age_avg_ms', float('nan')):7.1f}ms"
    return (f"{r['profile']:11s} {r['loss']:4.0f}% ({r['start']}): {f('setpoint')} | {f('sensor')} | "
            f"{f('image')} | offboard {'kept' if r.get('offboard_kept') else 'LOST'}{flown}"
            + (f" | session {r['session_formed_s']:.1f} s" if r.get("session_formed_s") is not None else ""))
