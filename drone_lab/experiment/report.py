"""Results of a sweep as CSV, markdown tables and figures (issue #17's "Done when").

One table set per (start mode, transport): the control streams (setpoint delivered %,
longest gap, p99 gap, gaps over PX4's 500 ms, p99 age; sensor delivered % and p99
age) and the images with the bandwidth (whole fresh frames/s and %, fresh strips %,
the age of the oldest strip in the picture for sliced images, kB/s each way). Cells
that measured nothing valid (``error``: no records; ``invalid``: a sender did not
stream through the whole window) are left out of the tables and listed under them
with their reason, so a broken cell never reads as a rate. Command success per loss
comes from the commands experiment's ``--jsonl`` file (``commands.py``), if given.

``python -m drone_lab.experiment.report OUT_DIR [--commands FILE.jsonl]`` redraws
everything from ``OUT_DIR/results.jsonl`` (``zenoh-robot experiment --report-only`` does the
same without commands).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

TOPICS = ("setpoint", "sensor", "image")
FIELDS = ("delivered_pct", "age_avg_ms", "age_p50_ms", "age_p99_ms", "age_max_ms", "period_avg_ms",
          "period_max_ms", "longest_gap_ms", "gap_p99_ms", "gaps_over_500ms", "rate_hz", "sent", "unique")
PROFILE_ORDER = ("reliable", "best_effort", "resilient")
MAX_SLICES = 4096      # image_strip records number strips frame * MAX_SLICES + index (image_transport.MAX_SLICES)

# The reference (ROS 2 Foxy + Fast DDS over Wi-Fi with netem), setpoint mean age by loss.
THESIS_SETPOINT = {
    "reliable": {0: "196 ms", 2: "780 ms", 9: "3.5 s", 50: "57 s", 60: "nothing", 70: "nothing", 80: "nothing",
                 90: "nothing"},
    "best_effort": {0: "10-20 ms", 50: "10-20 ms, msgs lost", 90: "10-20 ms, period 249 ms"},
}


def write_csv(results: list[dict[str, Any]], path: Path) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["start", "transport", "profile", "loss", "topic", *FIELDS, "offboard_kept", "invalid", "error"])
        for r in results:
            for topic in TOPICS + ("state", "image_whole", "image_strip"):
                s = r.get("topics", {}).get(topic, {})
                w.writerow([r.get("start"), r.get("transport", "default"), r.get("profile"), r.get("loss"), topic,
                            *(s.get(k) for k in FIELDS), r.get("offboard_kept"), r.get("invalid", ""),
                            r.get("error", "")])


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
    if not r.get("topics", {}).get("setpoint", {}).get("sent") and not r.get("link_failed"):
        return "invalid: no setpoint sent in the window"
    return None


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


def streams_table(rows: list[dict[str, Any]], commands: dict[float, dict[str, Any]] | None = None) -> str:
    """What keeps PX4 in OFFBOARD and the vehicle observed: setpoints and sensors."""
    head = ["loss", "profile", "setpoint delivered", "max gap", "p99 gap", "gaps > 500 ms", "setpoint p99 age",
            "sensor delivered", "sensor p99 age"]
    if commands is not None:
        head.append("commands answered in time")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        t = r.get("topics", {})
        sp, se = t.get("setpoint", {}), t.get("sensor", {})
        cells = [f"{float(r['loss']):g}%", str(r["profile"]), _pct(sp.get("delivered_pct")),
                 _fmt_ms(sp.get("longest_gap_ms")), _fmt_ms(sp.get("gap_p99_ms")), str(sp.get("gaps_over_500ms", "-")),
                 _fmt_ms(sp.get("age_p99_ms")), _pct(se.get("delivered_pct")), _fmt_ms(se.get("age_p99_ms"))]
        if commands is not None:
            cells.append(_command_cell(commands, float(r["loss"])))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def images_table(rows: list[dict[str, Any]]) -> str:
    """Frames as the viewer sees them (whole and fresh: every strip from this frame), and the bytes."""
    head = ["loss", "profile", "image mode", "whole fresh frames/s", "whole fresh %", "fresh strips %",
            "oldest strip p99 age", "GCS -> drone kB/s", "drone -> GCS kB/s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        t = r.get("topics", {})
        whole, strip = t.get("image_whole", {}), t.get("image_strip", {})
        mode = str(r.get("config", {}).get("image_mode", "-"))
        oldest = r.get("image_oldest_strip", {}).get("age_p99_ms") if mode == "sliced" else None
        bw = r.get("bandwidth_kBps", {})
        lines.append("| " + " | ".join([
            f"{float(r['loss']):g}%", str(r["profile"]), mode, _num(whole.get("rate_hz")),
            # A FEC frame is whole or not shown: its strips are exactly as fresh as its frames.
            _pct(whole.get("delivered_pct"), 0), _pct((whole if mode == "fec" else strip).get("delivered_pct"), 0),
            _fmt_ms(oldest) if mode == "sliced" else "n/a", _num(bw.get("gcs")), _num(bw.get("drone")),
        ]) + " |")
    return "\n".join(lines)


def skipped_list(rows: list[dict[str, Any]]) -> str:
    bad = [(r, skipped_reason(r)) for r in rows]
    items = [f"- {float(r.get('loss', math.nan)):g}% {r.get('profile')}: {why}" for r, why in bad if why]
    failed = [f"- {float(r.get('loss', math.nan)):g}% {r.get('profile')}: {r['link_failed']}"
              for r in rows if r.get("link_failed")]
    parts = (["Cells left out (not measurements):", *items] if items else []) + \
        (["Cells where the link failed the stack (both apps ran; counted as 0 % delivered):", *failed]
         if failed else [])
    return "\n".join(parts)


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
        path = out_dir / "cells" / f"{r.get('start')}-{r.get('profile')}-{float(r.get('loss', 0)):g}" / "gcs.json"
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
            pts = sorted((float(r["loss"]), r["topics"]) for r in rows if r["profile"] == profile)
            loss = [p[0] for p in pts]
            axes[0].plot(loss, [p[1].get("image_whole", {}).get("rate_hz", math.nan) for p in pts], marker="o",
                         label=profile)
            axes[1].plot(loss, [p[1].get("setpoint", {}).get("longest_gap_ms", math.nan) for p in pts], marker="o",
                         label=profile)
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
                pts = sorted((float(r["loss"]), r["topics"].get(topic, {})) for r in rows if r["profile"] == profile)
                loss = [p[0] for p in pts]
                for ax, key in zip(axes, ("delivered_pct", "age_avg_ms", "period_avg_ms"), strict=True):
                    ax.plot(loss, [p[1].get(key, math.nan) for p in pts], marker="o", label=profile)
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


def markdown_report(results: list[dict[str, Any]], commands: dict[float, dict[str, Any]] | None = None) -> str:
    md = ["# Lossy-link experiment", ""]
    for (start, transport), cells in groups(results).items():
        rows = [r for r in cells if skipped_reason(r) is None]
        md += [f"## Loss {'applied after set-up' if start == 'after' else 'present from start-up'}, "
               f"transport {transport}", ""]
        if rows:
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
           "(all streams, copies, probes and Zenoh's own packets).", ""]
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
    results = load_results(args.out / "results.jsonl")
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
