"""The benchmark's table (terminal and markdown), with the targets of the issue beside the ratios."""
from __future__ import annotations

import math
from typing import Any

from rich.table import Table
from rich.text import Text

from .runner import CellResult, spread

# Issue #30's targets (figures to read, never asserted: the machines are shared and noisy).
TARGETS = {"small_p50": 1.1, "image_p50": 1.05, "throughput": 0.9, "soak_mb": 5.0}


def _f(v: float, fmt: str = "{:.2f}") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def rows(results: list[CellResult]) -> list[list[str]]:
    out = []
    for r in results:
        c, fw, raw = r.cell, r.framework, r.raw
        what = f"{c.rate:g} Hz" if c.kind == "latency" else "max"
        if c.kind == "latency":
            target = TARGETS["image_p50"] if c.payload in ("image", "jpeg") else TARGETS["small_p50"]
            fig = (f"p50 {_f(fw.p50_ms, '{:.3f}')} / {_f(raw.p50_ms, '{:.3f}')} ms, "
                   f"p99 {_f(fw.p99_ms, '{:.2f}')} / {_f(raw.p99_ms, '{:.2f}')}")
            ratio = r.ratios.get("p50", math.nan)
            low, high = spread(r, "p50")
            verdict = "ok" if ratio <= target else f"over {target}x"
        else:
            fig = (f"{_f(fw.msgs_per_s, '{:.0f}')} / {_f(raw.msgs_per_s, '{:.0f}')} msg/s, "
                   f"{_f(fw.mb_per_s, '{:.1f}')} / {_f(raw.mb_per_s, '{:.1f}')} MB/s, "
                   f"lost {fw.sent - fw.received} / {raw.sent - raw.received}")
            ratio = r.ratios.get("throughput", math.nan)
            low, high = spread(r, "throughput")
            verdict = "ok" if ratio >= TARGETS["throughput"] else f"under {TARGETS['throughput']}x"
        cpu = (f"{_f(fw.cpu_us_per_msg_sub, '{:.0f}')} / {_f(raw.cpu_us_per_msg_sub, '{:.0f}')} "
               f"(set-up {_f(fw.cpu_ms_setup_sub, '{:.1f}')} / {_f(raw.cpu_ms_setup_sub, '{:.1f}')} ms)")
        err = fw.error or raw.error
        ratio_text = _f(ratio) if len(r.runs) < 2 else f"{_f(ratio)} ({_f(low)}-{_f(high)})"
        load = f"{r.load[0]:.1f}-{r.load[1]:.1f}" if math.isfinite(r.load[0]) else "-"
        out.append([c.payload, f"{r.payload_bytes} B", what, fig, ratio_text, str(len(r.runs)), load, cpu,
                    err[:40] if err else verdict])
    return out


HEAD = ["payload", "size", "rate", "framework / raw (medians)", "ratio median (spread)", "reps", "load",
        "sub CPU us/msg after the 1st sample, fw / raw (before it)", "target"]


# The full table needs ~150 columns; narrower terminals get one line a cell with the ratios (bench.md has all).
FULL_WIDTH = 150
COMPACT_HEAD = ["cell", "fw/raw (spread)", "sub CPU", "target"]
COMPACT_CAPTION = ("fw/raw: p50 age (Hz cells) or msg/s (max), framework / raw zenoh-python, median of the reps; "
                   "sub CPU: the subscriber's CPU per message after its first sample, framework / raw; "
                   "every figure: bench.md")


def table(results: list[CellResult], width: int = FULL_WIDTH) -> Table:
    """The terminal's table: every figure at ``width`` >= FULL_WIDTH, else a compact one that fits 80 columns."""
    express = ", express" if any(r.express for r in results) else ""
    t = Table(title=f"zenoh-robot vs raw zenoh-python (same run, same processes layout, same bytes{express})")
    if width >= FULL_WIDTH:
        for h in HEAD:
            t.add_column(h)
        for row in rows(results):
            t.add_row(*row)
        return t
    t.caption = COMPACT_CAPTION
    for h in COMPACT_HEAD:
        t.add_column(h, no_wrap=True)
    for r, row in zip(results, rows(results), strict=True):
        payload, size, rate, _fig, ratio_text, _reps, _load, _cpu, verdict = row
        cpu = r.ratios.get("cpu_sub", math.nan)
        t.add_row(f"{payload} {size} {rate}", ratio_text, _f(cpu) + ("x" if math.isfinite(cpu) else ""), verdict)
    return t


def markdown(results: list[CellResult], soak: dict[str, Any] | None) -> str:
    lines = ["| " + " | ".join(HEAD) + " |", "|" + "---|" * len(HEAD)]
    lines += ["| " + " | ".join(r) + " |" for r in rows(results)]
    if any(r.express for r in results):
        lines += ["", "Both sides published with Zenoh's express (each sample sent at once, no batching)."]
    if soak:
        lines += ["", f"Soak: {soak['minutes']:g} min at {soak['rate_hz']:g} Hz, subscriber RSS growth "
                      f"{_f(soak['rss_growth_mb'])} MB (target < {TARGETS['soak_mb']} MB), "
                      f"{soak['received']}/{soak['sent']} received."]
    return "\n".join(lines)


# -- zenoh-robot bench --ros2 in a terminal under FULL_WIDTH (its markdown, ros2.md, has every figure) ------------
ROS2_CAPTION = ("sdk: zenoh-ros2-sdk, the other Python rmw_zenoh; vs raw: p50 age (Hz cells) or msg/s (max), "
                "mode / raw zenoh-python, median (spread) of the reps; sub CPU: the subscriber's CPU per message, "
                "mode / raw; every figure: ros2.md")


def ros2_tables(codec: list[dict[str, Any]], e2e: list[dict[str, Any]]) -> list[Table]:
    """``bench --ros2``'s two tables, one line a type and a cell x mode, that fit 80 columns."""
    c = Table(title="codec, µs a message (encode / decode)", caption="rosbags: its codec alone, as before ours")
    for h in ("type", "CDR B", "ours", "rosbags", "msgpack"):
        c.add_column(h, no_wrap=True)
    for r in codec:
        c.add_row(r["type"].rsplit("/", 1)[-1], str(r["cdr_bytes"]),
                  f"{r['cdr_encode_us']:.1f} / {r['cdr_decode_us']:.1f}",
                  f"{r['rosbags_encode_us']:.1f} / {r['rosbags_decode_us']:.1f}",
                  f"{r['msgpack_encode_us']:.1f} / {r['msgpack_decode_us']:.1f}")
    # An error's text goes under the table (a wide cell would squeeze the others out of 80 columns).
    errors = list(dict.fromkeys(f"{r['mode']}: {r['error']}" for r in e2e if r.get("error")))
    t = Table(title="end to end, modes alternating", caption=Text("; ".join([ROS2_CAPTION, *errors])))
    for h in ("cell", "mode", "vs raw", "sub CPU", "received"):
        t.add_column(h, no_wrap=True)
    for r in e2e:
        short = r["type"].rsplit("/", 1)[-1]
        cell = f"{short} {r['rate_hz']:g} Hz" if r["rate_hz"] else f"{short} max"
        if r.get("error"):
            t.add_row(cell, r["mode"], "error (below)", "", "")
            continue
        ratio = _f(r["ratio"]) if r["reps"] < 2 else f"{_f(r['ratio'])} ({_f(r['ratio_low'])}-{_f(r['ratio_high'])})"
        cpu = r.get("cpu_sub_ratio", math.nan)
        t.add_row(cell, r["mode"], ratio, _f(cpu) + ("x" if math.isfinite(cpu) else ""), f"{r['received']}/{r['sent']}")
    return [c, t]
