"""Results of a sweep as CSV, markdown tables and figures (issues #17 and #29).

One table set per (start mode, transport), one row per (loss, profile and loss model), each
figure the median over the cell's runs with its range (``median [min-max]``):
- the flight (issue #29: every cell flies): runs whose mission succeeded, time armed in
  OFFBOARD over the window, companion failsafes, the age of the target the vehicle is given
  (max, and how often over PX4's 500 ms), path error against the pattern (mean, max), the
  mission's commands through the real companion (success, latency) and kB/s each way;
- the control streams (setpoints in the window: what "100 %" rests on, delivered %, longest
  gap, p99 gap, gaps over 500 ms, p99 age; sensor delivered % and p99 age; kB/s each way);
- the images with the bandwidth (whole fresh frames/s and %, fresh strips %, the age of the
  oldest strip in the picture for sliced images, kB/s each way).
Cells that measured nothing valid (``error``: no records; ``invalid``: a sender did not
stream through the whole window) are left out of the figures and listed under them with
their reason, so a broken cell never reads as a rate. Command success per loss from the
commands experiment's ``--jsonl`` file (``commands.py``), if given.

``python -m drone_lab.experiment.report OUT_DIR [--commands FILE.jsonl]`` redraws
everything from ``OUT_DIR/results.jsonl`` (``zenoh-robot experiment --report-only`` does the
same without commands).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

TOPICS = ("setpoint", "sensor", "image")
FIELDS = ("delivered_pct", "age_avg_ms", "age_p50_ms", "age_p99_ms", "age_max_ms", "period_avg_ms",
          "period_max_ms", "longest_gap_ms", "gap_p99_ms", "gaps_over_500ms", "rate_hz", "sent", "unique")
PROFILE_ORDER = ("reliable", "best_effort", "resilient")
MAX_SLICES = 4096      # image_strip records number strips frame * MAX_SLICES + index (zenoh_robot.image.MAX_SLICES)

# The reference (ROS 2 Foxy + Fast DDS over Wi-Fi with netem), setpoint mean age by loss.
THESIS_SETPOINT = {
    "reliable": {0: "196 ms", 2: "780 ms", 9: "3.5 s", 50: "57 s", 60: "nothing", 70: "nothing", 80: "nothing",
                 90: "nothing"},
    "best_effort": {0: "10-20 ms", 50: "10-20 ms, msgs lost", 90: "10-20 ms, period 249 ms"},
}


def write_csv(results: list[dict[str, Any]], path: Path) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["start", "transport", "profile", "loss", "run", "topic", *FIELDS, "offboard_kept",
                    *FLIGHT_CSV, "invalid", "error"])
        for r in results:
            fl = [get(r) for get in FLIGHT_CSV.values()]
            for topic in TOPICS + ("state", "image_whole", "image_strip"):
                s = r.get("topics", {}).get(topic, {})
                w.writerow([r.get("start"), r.get("transport", "default"), r.get("profile"), r.get("loss"),
                            r.get("run", 0), topic, *(s.get(k) for k in FIELDS), r.get("offboard_kept"), *fl,
                            r.get("invalid", ""), r.get("error", "")])


def _flight(r: dict[str, Any], *path: str) -> Any:
    node: Any = r.get("flight") or {}
    for key in path:
        node = node.get(key) if isinstance(node, dict) else None
    return node


def _gcs_repeater(key: str) -> Callable[[dict[str, Any]], Any]:
    """A figure of the GCS's repeater (``cell.analyse_cell``'s ``repeater``; None in older records)."""
    return lambda r: ((r.get("repeater") or {}).get("gcs") or {}).get(key)


FLIGHT_CSV: dict[str, Callable[[dict[str, Any]], Any]] = {
    "mission_ok": lambda r: _flight(r, "mission_ok"),
    "offboard_share": lambda r: _flight(r, "offboard_share_window"),
    "failsafes": lambda r: _flight(r, "failsafes"),
    "vehicle_target_age_max_ms": lambda r: _flight(r, "vehicle_target", "age_max_ms"),
    "vehicle_target_stale_over_500ms": lambda r: _flight(r, "vehicle_target", "stale_over_500ms"),
    "path_error_mean_m": lambda r: _flight(r, "path_error_window", "mean_m"),
    "path_error_max_m": lambda r: _flight(r, "path_error_window", "max_m"),
    "kBps_gcs": lambda r: (r.get("bandwidth_kBps") or {}).get("gcs"),
    "kBps_drone": lambda r: (r.get("bandwidth_kBps") or {}).get("drone"),
    "gcs_late_copies": _gcs_repeater("late"),
    "gcs_copy_max_late_ms": _gcs_repeater("max_late_ms"),
}


def _nan(v: object) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _fmt_ms(v: float | None) -> str:
    if _nan(v):
        return "-"
    assert v is not None
    return f"{v / 1000:.1f} s" if v >= 1000 else f"{v:.0f} ms" if v >= 10 else f"{v:.1f} ms"


def _pct(v: Any, digits: int = 1) -> str:
    return "-" if _nan(v) else f"{float(v):.{digits}f}%"


def _num(v: Any, digits: int = 1) -> str:
    return "-" if _nan(v) else f"{float(v):.{digits}f}"


def _profile_key(label: str) -> tuple[int, str]:
    base = label.split("@")[0]
    return (PROFILE_ORDER.index(base) if base in PROFILE_ORDER else len(PROFILE_ORDER), label)


def skipped_reason(r: dict[str, Any]) -> str | None:
    """Why a cell is not a measurement (None: it is one)."""
    if r.get("error"):
        return f"error: {r['error']}"
    if r.get("invalid"):
        return f"invalid: {r['invalid']}"
    if (not r.get("topics", {}).get("setpoint", {}).get("sent") and not r.get("link_failed")
            and not r.get("mission_failed")):
        # A mission that failed before the window (a session or a command the loss did not let
        # through, from start-up) is a failed flight, counted as one: only a window that missed
        # streams for the harness's own reasons is left out.
        return "invalid: no setpoint sent in the window"
    return None


def median_range(values: Iterable[Any], fmt: Callable[[float], str]) -> str:
    """``median [min-max]`` of the numbers among ``values`` (one value: itself; none: ``-``)."""
    nums = [float(v) for v in values if not _nan(v) and not isinstance(v, bool)]
    if not nums:
        return "-"
    mid = fmt(statistics.median(nums))
    return mid if len(nums) == 1 or min(nums) == max(nums) else f"{mid} [{fmt(min(nums))}-{fmt(max(nums))}]"


def runs_of(rows: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """``rows`` (one transport's valid cells) as one list of runs per (loss, profile), in table order."""
    out: dict[tuple[float, str], list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault((float(r.get("loss", 0)), str(r.get("profile"))), []).append(r)
    return [out[k] for k in sorted(out, key=lambda k: (k[0], _profile_key(k[1])))]


def _loss_label(r: dict[str, Any]) -> str:
    model = r.get("loss_model", "uniform")
    return f"{float(r['loss']):g}%" if model in (None, "uniform") else f"{float(r['loss']):g}% {model}"


def groups(results: Iterable[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """Cells by (start mode, transport), each sorted by loss then profile."""
    out: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in results:
        out.setdefault((str(r.get("start", "after")), str(r.get("transport", "default"))), []).append(r)
    for rows in out.values():
        rows.sort(key=lambda r: (float(r.get("loss", 0)), _profile_key(str(r.get("profile")))))
    order = {"after": 0, "startup": 1}
    return dict(sorted(out.items(), key=lambda kv: (order.get(kv[0][0], 9), kv[0][1] != "default", kv[0][1])))


def load_commands(path: Path) -> dict[float, dict[str, Any]]:
    """The commands experiment's rows by loss (its ``--jsonl``; the last row of a loss wins)."""
    by_loss: dict[float, dict[str, Any]] = {}
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
            by_loss[float(row["loss_pct"])] = row
        except (ValueError, KeyError, TypeError):
            continue   # a cut or foreign line
    return by_loss


def _command_cell(commands: dict[float, dict[str, Any]] | None, loss: float) -> str:
    row = (commands or {}).get(float(loss))
    if row is None:
        return "-"
    return f"{row.get('success_rate', math.nan) * 100:.0f}% of {row.get('calls', '?')}"


def _topic(name: str, key: str) -> Callable[[dict[str, Any]], Any]:
    return lambda r: r.get("topics", {}).get(name, {}).get(key)


def _bw(side: str) -> Callable[[dict[str, Any]], Any]:
    return lambda r: (r.get("bandwidth_kBps") or {}).get(side)


def _row(runs: list[dict[str, Any]], columns: Sequence[tuple[Callable[[dict[str, Any]], Any],
                                                               Callable[[Any], str]]]) -> list[str]:
    return [median_range((get(r) for r in runs), fmt) for get, fmt in columns]


def _int(v: float) -> str:
    return f"{v:.0f}"


def streams_table(rows: list[dict[str, Any]], commands: dict[float, dict[str, Any]] | None = None) -> str:
    """What reached each end: setpoints and sensors, with what the link carried (kB/s)."""
    head = ["loss", "profile", "runs", "setpoints in window", "setpoint delivered", "max gap", "p99 gap",
            "gaps > 500 ms", "setpoint p99 age", "sensor delivered", "sensor p99 age", "GCS -> drone kB/s",
            "drone -> GCS kB/s"]
    if commands is not None:
        head.append("commands answered in time")
    columns = [(_topic("setpoint", "sent"), _int), (_topic("setpoint", "delivered_pct"), _pct),
               (_topic("setpoint", "longest_gap_ms"), _fmt_ms), (_topic("setpoint", "gap_p99_ms"), _fmt_ms),
               (_topic("setpoint", "gaps_over_500ms"), _int), (_topic("setpoint", "age_p99_ms"), _fmt_ms),
               (_topic("sensor", "delivered_pct"), _pct), (_topic("sensor", "age_p99_ms"), _fmt_ms),
               (_bw("gcs"), _num), (_bw("drone"), _num)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for runs in runs_of(rows):
        r = runs[0]
        cells = [_loss_label(r), str(r["profile"]), str(len(runs)), *_row(runs, columns)]
        if commands is not None:
            cells.append(_command_cell(commands, float(r["loss"])))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _command(name: str) -> Callable[[dict[str, Any]], Any]:
    return lambda r: _flight(r, "commands", name, "s")


def _commands_ok(runs: list[dict[str, Any]]) -> str:
    """Mission commands (and the hold probe) that succeeded, over all runs."""
    done = [c for r in runs for c in (_flight(r, "commands") or {}).values()]
    return f"{sum(1 for c in done if c.get('ok'))}/{len(done)}" if done else "-"


def flight_table(rows: list[dict[str, Any]]) -> str:
    """The flight itself: OFFBOARD kept, failsafes, the target's age at the vehicle, path error, the
    commands through the real companion, and the bytes the link carried meanwhile."""
    head = ["loss", "profile", "runs", "mission ok", "OFFBOARD (window)", "failsafes", "target age at vehicle max",
            "target > 500 ms", "path error mean", "path error max", "commands ok", "offboard_start s", "arm s",
            "land s", "hold s (probe)", "GCS -> drone kB/s", "drone -> GCS kB/s"]
    columns = [(lambda r: _flight(r, "offboard_share_window"), lambda v: f"{100 * v:.0f}%"),
               (lambda r: _flight(r, "failsafes"), _int),
               (lambda r: _flight(r, "vehicle_target", "age_max_ms"), _fmt_ms),
               (lambda r: _flight(r, "vehicle_target", "stale_over_500ms"), _int),
               (lambda r: _flight(r, "path_error_window", "mean_m"), lambda v: f"{v:.2f} m"),
               (lambda r: _flight(r, "path_error_window", "max_m"), lambda v: f"{v:.2f} m")]
    tail = [(_command("offboard_start"), _sec), (_command("arm"), _sec), (_command("land"), _sec),
            (_command("hold"), _sec), (_bw("gcs"), _num), (_bw("drone"), _num)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for runs in runs_of(rows):
        r = runs[0]
        ok = sum(1 for x in runs if _flight(x, "mission_ok"))
        lines.append("| " + " | ".join([_loss_label(r), str(r["profile"]), str(len(runs)), f"{ok}/{len(runs)}",
                                        *_row(runs, columns), _commands_ok(runs), *_row(runs, tail)]) + " |")
    return "\n".join(lines)


def _sec(v: float) -> str:
    return f"{v:.2f}"


def images_table(rows: list[dict[str, Any]]) -> str:
    """Frames as the viewer sees them (whole and fresh: every strip from this frame), and the bytes."""
    head = ["loss", "profile", "image mode", "whole fresh frames/s", "whole fresh %", "fresh strips %",
            "oldest strip p99 age", "GCS -> drone kB/s", "drone -> GCS kB/s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for runs in runs_of(rows):
        r = runs[0]
        mode = str(r.get("config", {}).get("image_mode", "-"))
        # A FEC frame is whole or not shown: its strips are exactly as fresh as its frames.
        columns = [(_topic("image_whole", "rate_hz"), _num), (_topic("image_whole", "delivered_pct"), _pct0),
                   (_topic("image_whole" if mode == "fec" else "image_strip", "delivered_pct"), _pct0)]
        oldest = median_range((x.get("image_oldest_strip", {}).get("age_p99_ms") for x in runs), _fmt_ms)
        lines.append("| " + " | ".join([
            _loss_label(r), str(r["profile"]), mode, *_row(runs, columns), oldest if mode == "sliced" else "n/a",
            *_row(runs, [(_bw("gcs"), _num), (_bw("drone"), _num)]),
        ]) + " |")
    return "\n".join(lines)


def _pct0(v: Any) -> str:
    return _pct(v, 0)


def skipped_list(rows: list[dict[str, Any]]) -> str:
    bad = [(r, skipped_reason(r)) for r in rows]
    items = [f"- {float(r.get('loss', math.nan)):g}% {r.get('profile')}{_run_tag(r)}: {why}" for r, why in bad if why]
    failed = [f"- {float(r.get('loss', math.nan)):g}% {r.get('profile')}{_run_tag(r)}: {r['link_failed']}"
              for r in rows if r.get("link_failed")]
    # Every failed flight, the ones that failed after their window too (a land whose answer was lost).
    flights = [f"- {float(r.get('loss', math.nan)):g}% {r.get('profile')}{_run_tag(r)}: "
               f"{r.get('mission_failed') or r['flight'].get('mission_result', 'no mission record')}"
               for r in rows if r.get("mission_failed")
               or (r.get("flight") and not r["flight"].get("mission_ok") and not skipped_reason(r))]
    parts = (["Cells left out (not measurements):", *items] if items else []) + \
        (["Cells where the link failed the stack (both apps ran; counted as 0 % delivered):", *failed]
         if failed else []) + \
        (["Flights that failed (a result: their figures are in the tables):", *flights] if flights else [])
    return "\n".join(parts)


def _run_tag(r: dict[str, Any]) -> str:
    return f" run {r['run']}" if "run" in r else ""


def oldest_strip_ages(strips: dict[str, Any], t0_ns: int, t1_ns: int) -> dict[str, float]:
    """The age of the oldest strip in the picture a sliced viewer shows, at every strip arrival
    in [t0, t1]: each strip index shows its newest strip received so far (older frames patch the
    gaps). From the GCS's ``image_strip`` record (seq = frame * MAX_SLICES + index)."""
    newest: dict[int, tuple[int, int]] = {}        # index -> (frame, source stamp)
    ages: list[float] = []
    order = sorted(zip(strips.get("arrival_ns", []), strips.get("seq", []), strips.get("stamp_ns", []),
                       strict=False))
    for arrival, seq, stamp in order:
        frame, index = divmod(int(seq), MAX_SLICES)
        if index not in newest or newest[index][0] < frame:
            newest[index] = (frame, int(stamp))
        if t0_ns <= arrival <= t1_ns:
            ages.append((arrival - min(s for _, s in newest.values())) / 1e6)
    if not ages:
        return {"samples": 0, "age_p50_ms": math.nan, "age_p99_ms": math.nan, "age_max_ms": math.nan}
    ages.sort()

    def q(p: float) -> float:
        return ages[min(len(ages) - 1, int(p * len(ages)))]
    return {"samples": len(ages), "age_p50_ms": q(0.5), "age_p99_ms": q(0.99), "age_max_ms": ages[-1]}


def add_oldest_strip_ages(results: list[dict[str, Any]], out_dir: Path) -> None:
    """Fill ``image_oldest_strip`` of sliced cells from their raw GCS record (``cells/<cell>/gcs.json``,
    as sweep.py lays them out), where it is still on disk and the cell does not carry it yet."""
    for r in results:
        if r.get("config", {}).get("image_mode") != "sliced" or "image_oldest_strip" in r or not r.get("window_ns"):
            continue
        name = r.get("cell_dir") or f"{r.get('start')}-{r.get('profile')}-{float(r.get('loss', 0)):g}"
        path = out_dir / "cells" / str(name) / "gcs.json"
        try:
            drones = json.loads(path.read_text())["drones"]
            strips = next(iter(drones.values()))["logs"]["received"]["image_strip"]
        except (OSError, ValueError, KeyError, StopIteration):
            continue
        r["image_oldest_strip"] = oldest_strip_ages(strips, *r["window_ns"])


def draw_figures(results: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for (start, transport), cells in groups(results).items():
        rows = [r for r in cells if skipped_reason(r) is None]
        if not rows:
            continue
        tag = start if transport == "default" else f"{start}_{transport}"
        where = f"loss applied {'after set-up' if start == 'after' else 'from start-up'}, transport {transport}"
        # The two figures the issue asks for: what the pilot sees and what keeps PX4 in OFFBOARD.
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        for profile in sorted({str(r["profile"]) for r in rows}, key=_profile_key):
            loss, frames = _run_medians(rows, profile, "image_whole", "rate_hz")
            axes[0].plot(loss, frames, marker="o", label=profile)
            axes[1].plot(*_run_medians(rows, profile, "setpoint", "longest_gap_ms"), marker="o", label=profile)
        axes[0].set_ylabel("whole fresh frames/s")
        axes[1].set_ylabel("longest setpoint gap (ms)")
        axes[1].set_yscale("log")
        axes[1].axhline(500, color="red", linestyle="--", linewidth=1, label="PX4 OFFBOARD limit")
        for ax in axes:
            ax.set_xlabel("packet loss % (each way)")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
        fig.suptitle(where)
        fig.tight_layout()
        path = out_dir / f"summary_{tag}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
        for topic in TOPICS:
            fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
            for profile in sorted({str(r["profile"]) for r in rows}, key=_profile_key):
                for ax, key in zip(axes, ("delivered_pct", "age_avg_ms", "period_avg_ms"), strict=True):
                    ax.plot(*_run_medians(rows, profile, topic, key), marker="o", label=profile)
            axes[0].set_ylabel("delivered %")
            axes[0].set_ylim(0, 105)
            axes[1].set_ylabel("mean message age (ms)")
            axes[2].set_ylabel("mean message period (ms)")
            for ax in axes[1:]:
                ax.set_yscale("log")
            for ax in axes:
                ax.set_xlabel("packet loss %")
                ax.grid(True, which="both", alpha=0.3)
                ax.legend()
            fig.suptitle(f"{topic}: {where}")
            fig.tight_layout()
            path = out_dir / f"{topic}_{tag}.png"
            fig.savefig(path, dpi=90)
            plt.close(fig)
            paths.append(path)
    return paths


def _run_medians(rows: list[dict[str, Any]], profile: str, stream: str, figure: str) -> tuple[list[float], list[float]]:
    """(uniform loss levels, the median over each cell's runs of ``stream``'s ``figure``): a figure's line. A
    bursty cell is no point on a uniform-loss axis; its figures are in the tables."""
    runs: dict[float, list[float]] = {}
    for r in rows:
        if r["profile"] == profile and r.get("loss_model", "uniform") == "uniform":
            runs.setdefault(float(r["loss"]), []).append(r["topics"].get(stream, {}).get(figure, math.nan))
    loss = sorted(runs)
    return loss, [statistics.median(runs[x]) for x in loss]


def markdown_report(results: list[dict[str, Any]], commands: dict[float, dict[str, Any]] | None = None) -> str:
    md = ["# Lossy-link experiment", ""]
    for (start, transport), cells in groups(results).items():
        rows = [r for r in cells if skipped_reason(r) is None]
        md += [f"## Loss {'applied after set-up' if start == 'after' else 'present from start-up'}, "
               f"transport {transport}", ""]
        if rows:
            if any(r.get("flight") for r in rows):
                md += ["### Flight", "", flight_table([r for r in rows if r.get("flight")]), ""]
            md += ["### Setpoints and sensors", "", streams_table(rows, commands), "",
                   "### Images and bandwidth", "", images_table(rows), ""]
        else:
            md += ["No valid cell.", ""]
        skipped = skipped_list(cells)
        if skipped:
            md += [skipped, ""]
    md += ["Delivered %: unique sequence numbers received / sent in the window. Gaps: the longest time with "
           "nothing new (window edges included), its 99th percentile, and how often it exceeded PX4's 500 ms "
           "OFFBOARD limit. Whole fresh frames: frames whose every strip is from that frame (a raw or FEC frame "
           "is one piece). Oldest strip age: at each strip arrival, now minus the publication of the oldest "
           "strip in the picture (sliced images only). kB/s: everything each side put on its veth "
           "(all streams, copies, probes and Zenoh's own packets), in the window. Each figure: the median over "
           "the cell's runs, [min-max] when they differ; setpoints in window: how many sent, what \"100 %\" "
           "rests on (none lost of n bounds the loss rate under 3/n at 95 %).", "",
           "Flight: the GCS's mission (`gcs --mission`: OFFBOARD, arm, climb, the pattern, land) through the "
           "loss. OFFBOARD (window): share of the window PX4 was armed in OFFBOARD; failsafes: the companion's "
           "deadline HOLDs; target age at vehicle: now minus the GCS stamp of the target px4_link streams to "
           "PX4 (sampled every 20 ms by `companion --vehicle-record`; px4_link re-sends it at 20 Hz, so this, "
           "not PX4's stream, is the gap that matters), and how often it went over 500 ms; path error: the "
           "vehicle's horizontal distance from the pattern's path in the window; commands: the mission's "
           "offboard_start, arm and land through the real companion (latency from its step times, within "
           "0.2 s) and a hold from a second GCS mid-window (refused: it holds no control; process start-up "
           "and session included).", ""]
    if commands is not None:
        md += ["Commands answered in time: the commands experiment (`python -m drone_lab.experiment."
               "commands --jsonl FILE`), its own run over the same kind of link, joined by loss.", ""]
        from .commands import table as commands_table
        md += ["## Commands", "", commands_table([commands[k] for k in sorted(commands)]), ""]
    else:
        md += ["Command success per loss: not in this report (give `--commands FILE.jsonl` from "
               "`python -m drone_lab.experiment.commands --jsonl FILE`; see docs/results/commands.md).", ""]
    return "\n".join(md)


def write_report(results: list[dict[str, Any]], out_dir: Path, commands: Path | None = None) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    add_oldest_strip_ages(results, out_dir)
    write_csv(results, out_dir / "results.csv")
    (out_dir / "results.md").write_text(markdown_report(results, load_commands(commands) if commands else None))
    figures = draw_figures(results, out_dir)
    (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    return {"csv": out_dir / "results.csv", "markdown": out_dir / "results.md", "json": out_dir / "results.json",
            **{p.stem: p for p in figures}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m drone_lab.experiment.report", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path, help="the experiment's --out directory (holds results.jsonl)")
    ap.add_argument("--commands", type=Path, help="the commands experiment's --jsonl file")
    args = ap.parse_args(argv)
    from .sweep import load_results
    results = load_results(args.out / "results.jsonl", include_invalid=True)
    if not results:
        print(f"no results in {args.out / 'results.jsonl'}")
        return 2
    files = write_report(results, args.out, args.commands)
    print((args.out / "results.md").read_text())
    for name, path in files.items():
        print(f"{name}: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
