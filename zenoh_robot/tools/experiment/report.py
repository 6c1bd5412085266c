"""Results of a sweep as CSV, a markdown table beside the thesis's numbers, and figures."""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

TOPICS = ("setpoint", "sensor", "image")
FIELDS = ("delivered_pct", "age_avg_ms", "age_p50_ms", "age_p99_ms", "age_max_ms", "period_avg_ms",
          "period_max_ms", "longest_gap_ms", "gap_p99_ms", "gaps_over_500ms", "rate_hz", "sent", "unique")

# The reference (ROS 2 Foxy + Fast DDS over Wi-Fi with netem), setpoint mean age by loss.
THESIS_SETPOINT = {
    "reliable": {0: "196 ms", 2: "780 ms", 9: "3.5 s", 50: "57 s", 60: "nothing", 70: "nothing", 80: "nothing",
                 90: "nothing"},
    "best_effort": {0: "10-20 ms", 50: "10-20 ms, msgs lost", 90: "10-20 ms, period 249 ms"},
}


def write_csv(results: list[dict[str, Any]], path: Path) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["start", "profile", "loss", "topic", *FIELDS, "offboard_kept", "error"])
        for r in results:
            for topic in TOPICS + ("state", "image_whole", "image_strip"):
                s = r.get("topics", {}).get(topic, {})
                w.writerow([r.get("start"), r.get("profile"), r.get("loss"), topic, *(s.get(k) for k in FIELDS),
                            r.get("offboard_kept"), r.get("error", "")])


def _fmt_ms(v: float | None) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v / 1000:.1f} s" if v >= 1000 else f"{v:.0f} ms" if v >= 10 else f"{v:.1f} ms"


def _cell(s: dict[str, Any] | None) -> str:
    if not s or not s.get("sent"):
        return "-"
    return f"{s['delivered_pct']:.0f}% / {_fmt_ms(s['age_avg_ms'])}"


def markdown_table(results: list[dict[str, Any]], start: str = "after") -> str:
    rows = [r for r in results if r.get("start") == start]
    profiles = sorted({r["profile"] for r in rows}, key=lambda p: ("reliable", "best_effort", "resilient").index(p)
                      if p in ("reliable", "best_effort", "resilient") else 9)
    losses = sorted({float(r["loss"]) for r in rows})
    by = {(r["profile"], float(r["loss"])): r for r in rows}
    head = ["loss"] + [f"{topic} {p}" for topic in TOPICS for p in profiles] + ["thesis setpoint (rel / BE)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for loss in losses:
        cells = [f"{loss:g}%"]
        for topic in TOPICS:
            for p in profiles:
                r = by.get((p, loss))
                if r is None:
                    cells.append("")
                elif r.get("error"):
                    cells.append("error")
                else:
                    cells.append(_cell(r["topics"].get(topic)))
        thesis = [THESIS_SETPOINT[p].get(int(loss), "") for p in ("reliable", "best_effort")]
        cells.append(" / ".join(t or "·" for t in thesis))
        lines.append("| " + " | ".join(cells) + " |")
    kept = [f"{p}: {sum(1 for r in rows if r['profile'] == p and r.get('offboard_kept'))}/"
            f"{sum(1 for r in rows if r['profile'] == p)}" for p in profiles]
    lines.append("")
    lines.append("Each cell: delivered % (unique sequence numbers received / sent) / mean age. "
                 "Cells where PX4 would have stayed in OFFBOARD (no setpoint gap over 500 ms): " + ", ".join(kept))
    return "\n".join(lines)


def setpoint_table(results: list[dict[str, Any]], start: str = "after") -> str:
    """What keeps PX4 in OFFBOARD, and what it costs: setpoint gaps and the bytes on the wire."""
    rows = sorted((r for r in results if r.get("start") == start and not r.get("error")),
                  key=lambda r: (float(r["loss"]), str(r["profile"])))
    head = ["loss", "profile", "setpoint delivered", "max gap", "p99 gap", "gaps > 500 ms", "p99 age",
            "GCS -> drone kB/s", "drone -> GCS kB/s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        sp = r.get("topics", {}).get("setpoint", {})
        bw = r.get("bandwidth_kBps", {})
        lines.append("| " + " | ".join([
            f"{float(r['loss']):g}%", str(r["profile"]), f"{sp.get('delivered_pct', math.nan):.1f}%",
            _fmt_ms(sp.get("longest_gap_ms")), _fmt_ms(sp.get("gap_p99_ms")), str(sp.get("gaps_over_500ms", "-")),
            _fmt_ms(sp.get("age_p99_ms")), f"{bw.get('gcs', math.nan):.1f}", f"{bw.get('drone', math.nan):.1f}",
        ]) + " |")
    return "\n".join(lines)


def image_table(results: list[dict[str, Any]], start: str = "after") -> str:
    """Frames as the viewer sees them: shown, whole and fresh (every strip from this frame), fresh strips."""
    rows = sorted((r for r in results if r.get("start") == start and not r.get("error")),
                  key=lambda r: (float(r["loss"]), str(r["profile"])))
    head = ["loss", "profile", "image mode", "frames shown /s", "whole fresh frames /s", "whole fresh %",
            "fresh strips %", "p50 age", "drone -> GCS kB/s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        t = r.get("topics", {})
        shown, whole, strip = t.get("image", {}), t.get("image_whole", {}), t.get("image_strip", {})
        lines.append("| " + " | ".join([
            f"{float(r['loss']):g}%", str(r["profile"]), str(r.get("config", {}).get("image_mode", "-")),
            f"{shown.get('rate_hz', math.nan):.1f}", f"{whole.get('rate_hz', math.nan):.1f}",
            f"{whole.get('delivered_pct', math.nan):.0f}%", f"{strip.get('delivered_pct', math.nan):.0f}%",
            _fmt_ms(whole.get("age_p50_ms")), f"{r.get('bandwidth_kBps', {}).get('drone', math.nan):.1f}",
        ]) + " |")
    return "\n".join(lines)


def draw_figures(results: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for start in sorted({r.get("start", "after") for r in results}):
        rows = [r for r in results if r.get("start") == start and not r.get("error")]
        if not rows:
            continue
        for topic in TOPICS:
            fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
            for profile in sorted({r["profile"] for r in rows}):
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
            fig.suptitle(f"{topic}: loss applied {'after set-up' if start == 'after' else 'from start-up'}")
            fig.tight_layout()
            path = out_dir / f"{topic}_{start}.png"
            fig.savefig(path, dpi=90)
            plt.close(fig)
            paths.append(path)
    return paths


def write_report(results: list[dict[str, Any]], out_dir: Path) -> dict[str, Path]:
    write_csv(results, out_dir / "results.csv")
    md = ["# Lossy-link experiment", ""]
    for start in ("after", "startup"):
        if any(r.get("start") == start for r in results):
            md += [f"## Loss {'applied after set-up' if start == 'after' else 'present from start-up'}", "",
                   markdown_table(results, start), "", "### Setpoint gaps and bandwidth", "",
                   setpoint_table(results, start), "", "### Images: whole fresh frames", "",
                   image_table(results, start), ""]
    (out_dir / "results.md").write_text("\n".join(md))
    figures = draw_figures(results, out_dir)
    import json
    (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    return {"csv": out_dir / "results.csv", "markdown": out_dir / "results.md", "json": out_dir / "results.json",
            **{p.stem: p for p in figures}}
