"""Benchmark cells: the same two-process layout through the framework and through raw zenoh-python."""
from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from zenoh_robot.message import type_support


@dataclass(frozen=True)
class Cell:
    payload: str
    kind: str           # "latency" or "throughput"
    rate: float         # Hz for latency cells; 0 for throughput
    count: int


@dataclass
class Figures:
    received: int = 0
    sent: int = 0
    p50_ms: float = math.nan
    p99_ms: float = math.nan
    msgs_per_s: float = math.nan
    mb_per_s: float = math.nan
    cpu_us_per_msg_pub: float = math.nan
    cpu_us_per_msg_sub: float = math.nan     # after the first sample, over samples 2..n
    cpu_ms_setup_sub: float = math.nan       # from ready to the first sample (the publisher's discovery)
    rss_growth_mb: float = math.nan
    error: str = ""


@dataclass
class CellResult:
    """One cell: the median figures of its repetitions, and each repetition's ratios (their spread)."""
    cell: Cell
    framework: Figures
    raw: Figures
    payload_bytes: int
    ratios: dict[str, float] = field(default_factory=dict)     # medians over the repetitions
    runs: list[dict[str, float]] = field(default_factory=list)  # per repetition: ratios and the load average
    load: tuple[float, float] = (math.nan, math.nan)            # 1-minute load average: min, max over the cell
    receive: str = "default"
    express: bool = False       # both sides' publishers sent with Zenoh's express (no batching)


def plan(quick: bool = False, only: list[str] | None = None) -> list[Cell]:
    scale = 0.1 if quick else 1.0

    def n(x: float) -> int:
        return max(20, int(x * scale))
    cells = []
    for payload in ("setpoint", "sensor"):
        cells += [Cell(payload, "latency", 10, n(50)), Cell(payload, "latency", 200, n(1000)),
                  Cell(payload, "latency", 1000, n(3000)), Cell(payload, "throughput", 0, n(30000))]
    for payload in ("image", "jpeg"):
        cells += [Cell(payload, "latency", 30, n(150)), Cell(payload, "throughput", 0, n(600))]
    return [c for c in cells if not only or c.payload in only]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def run_pair(mode: str, cell: Cell, timeout: float, rss_every: float = 0.0, receive: str | None = None,
             express: bool = False) -> Figures:
    port = _free_port()
    common = [cell.payload, "--count", str(cell.count), "--port", str(port)]
    if express:
        common.append("--express")
    if receive is not None and mode == "framework":
        common += ["--receive", receive]
    if cell.kind == "throughput":
        common.append("--throughput")
    worker = [sys.executable, "-m", "zenoh_robot.tools.bench.worker"]
    sub = subprocess.Popen(worker + ["sub", mode, *common, "--timeout", str(timeout), "--rss-every", str(rss_every)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert sub.stdout is not None and sub.stderr is not None   # both are PIPEs
        if sub.stdout.readline().strip() != "READY":
            return Figures(error=f"subscriber did not start: {sub.stderr.read()[-300:]}")
        pub = subprocess.run(worker + ["pub", mode, *common, "--rate", str(cell.rate)], capture_output=True,
                             text=True, timeout=timeout + 30)
        out, err = sub.communicate(timeout=timeout + 30)
    finally:
        if sub.poll() is None:
            sub.kill()
    if pub.returncode or sub.returncode:
        return Figures(error=f"worker failed: {(pub.stderr or err)[-300:]}")
    p, s = json.loads(pub.stdout.strip().splitlines()[-1]), json.loads(out.strip().splitlines()[-1])
    ages = np.array(s["ages_ms"])
    f = Figures(received=s["received"], sent=p["sent"])
    if ages.size:
        f.p50_ms, f.p99_ms = float(np.percentile(ages, 50)), float(np.percentile(ages, 99))
    if s["received"] > 1 and s["t_last"] > s["t_first"]:
        f.msgs_per_s = (s["received"] - 1) / (s["t_last"] - s["t_first"])
    f.cpu_us_per_msg_pub = p["cpu_s"] / max(p["sent"], 1) * 1e6
    f.cpu_us_per_msg_sub = s["cpu_s"] / max(s["received"] - 1, 1) * 1e6
    f.cpu_ms_setup_sub = s["cpu_setup_s"] * 1e3
    if len(s["rss_mb"]) >= 2:
        f.rss_growth_mb = s["rss_mb"][-1] - s["rss_mb"][0]
    return f


def _ratios(cell: Cell, fw: Figures, raw: Figures) -> dict[str, float]:
    ratios = {}
    if cell.kind == "latency":
        ratios["p50"] = fw.p50_ms / raw.p50_ms if raw.p50_ms else math.nan
        ratios["p99"] = fw.p99_ms / raw.p99_ms if raw.p99_ms else math.nan
    else:
        ratios["throughput"] = fw.msgs_per_s / raw.msgs_per_s if raw.msgs_per_s else math.nan
    ratios["cpu_sub"] = fw.cpu_us_per_msg_sub / raw.cpu_us_per_msg_sub if raw.cpu_us_per_msg_sub else math.nan
    return ratios


def _median_figures(runs: list[Figures]) -> Figures:
    """Each figure's median over the repetitions (counts: the worst, so a loss is never hidden)."""
    ok = [f for f in runs if not f.error] or runs
    out = Figures(received=min(f.received for f in ok), sent=max(f.sent for f in ok),
                  error=next((f.error for f in runs if f.error), ""))
    for name in ("p50_ms", "p99_ms", "msgs_per_s", "mb_per_s", "cpu_us_per_msg_pub", "cpu_us_per_msg_sub",
                 "cpu_ms_setup_sub", "rss_growth_mb"):
        values = [getattr(f, name) for f in ok if math.isfinite(getattr(f, name))]
        setattr(out, name, float(np.median(values)) if values else math.nan)
    return out


def run_cell(cell: Cell, reps: int = 1, receive: str | None = None, express: bool = False) -> CellResult:
    """``reps`` alternating repetitions (framework, raw, framework, raw, ...): load that comes and
    goes on a shared machine then falls on both sides alike. Ratios are medians of each
    repetition's own ratio; ``runs`` keeps them all (the spread) with the load average of each."""
    from . import payloads
    msg = payloads.make(cell.payload)
    size = len(__import__("msgpack").packb(type_support(type(msg)).encode(msg), use_bin_type=True))
    timeout = max(30.0, cell.count / cell.rate * 2 + 20) if cell.rate else 90.0
    fws: list[Figures] = []
    raws: list[Figures] = []
    runs: list[dict[str, float]] = []
    for _ in range(max(1, reps)):
        fw = run_pair("framework", cell, timeout, receive=receive, express=express)
        raw = run_pair("raw", cell, timeout, express=express)
        for f in (fw, raw):
            f.mb_per_s = f.msgs_per_s * size / 1e6 if cell.kind == "throughput" else math.nan
        fws.append(fw)
        raws.append(raw)
        runs.append({**_ratios(cell, fw, raw), "load1": os.getloadavg()[0]})
    ratios = {k: float(np.median([r[k] for r in runs if math.isfinite(r[k])] or [math.nan]))
              for k in runs[0] if k != "load1"}
    loads = [r["load1"] for r in runs]
    return CellResult(cell, _median_figures(fws), _median_figures(raws), size, ratios, runs,
                      (min(loads), max(loads)), receive or "default", express)


def spread(result: CellResult, key: str) -> tuple[float, float]:
    """The lowest and highest per-repetition ratio ``key`` of a cell."""
    values = [r[key] for r in result.runs if key in r and math.isfinite(r[key])]
    return (min(values), max(values)) if values else (math.nan, math.nan)


def run_soak(minutes: float, rate: float = 1000.0) -> dict[str, Any]:
    cell = Cell("setpoint", "latency", rate, int(minutes * 60 * rate))
    f = run_pair("framework", cell, timeout=minutes * 60 + 60, rss_every=10.0)
    return {"minutes": minutes, "rate_hz": rate, "received": f.received, "sent": f.sent,
            "rss_growth_mb": f.rss_growth_mb, "p50_ms": f.p50_ms, "p99_ms": f.p99_ms, "error": f.error}


def run_all(cells: list[Cell], progress: Callable[[Cell], None] | None = None, reps: int = 1,
            receive: str | None = None, express: bool = False) -> list[CellResult]:
    results = []
    for cell in cells:
        if progress:
            progress(cell)
        results.append(run_cell(cell, reps, receive, express))
    return results


def to_json(results: list[CellResult], soak: dict[str, Any] | None, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"cells": [asdict(r) for r in results], "soak": soak}, indent=1))
