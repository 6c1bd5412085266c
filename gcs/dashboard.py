"""The GCS dashboard: one row per drone (readable at 10-20 drones), one drone's streams on demand.

Rates are counted over a sliding window (``RateMeter``, 3 s) instead of the last refresh:
at a 4 Hz refresh a 5 Hz stream delivers one or two samples per refresh, which showed as
3.9 <-> 7.8 Hz. Without a terminal (a pipe, a log file) the GCS prints ``plain_lines``:
short lines, one per drone, only what is known (no padding, no ``nan``).

Images are shown as honestly as the picture is: frames shown per second, whole fresh
frames per second (every strip of the frame arrived), the percentage of strips that arrived
(frames skipped entirely included; FEC and whole-image modes count frames) and the age of
the oldest strip in the latest picture (a patched strip is as old as the frame it came from).
All from the image receiver's counters (``zenoh_robot.image``): nothing is decoded to show them.
"""
from __future__ import annotations

import math
import time
from collections import deque

from rich.console import Group
from rich.table import Table

from drone_contract.messages import VehicleState

from .app import DroneView, Gcs

WINDOW_S = 3.0


def _ms(v: float) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:7.1f}"


class RateMeter:
    """Rate of a cumulative counter over the last ``window`` seconds (steady at any refresh rate)."""

    def __init__(self, window: float = WINDOW_S) -> None:
        self.window = window
        self._hist: dict[str, deque[tuple[float, int]]] = {}

    def rate(self, key: str, count: int, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        hist = self._hist.setdefault(key, deque())
        hist.append((now, count))
        while len(hist) > 2 and now - hist[1][0] >= self.window:
            hist.popleft()   # keep one point at or beyond the window's start
        t0, c0 = hist[0]
        return (count - c0) / (now - t0) if now - t0 >= 0.5 else float("nan")


def _hz(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:5.1f}"


def drone_figures(d: DroneView, rates: RateMeter) -> dict[str, float]:
    """Windowed rates of one drone's streams (what the row and the plain line show)."""
    out = {name: rates.rate(f"{d.id}/{name}", len(rec)) for name, rec in d.streams.items()}
    out["setpoint"] = rates.rate(f"{d.id}/setpoint", d.setpoints_sent)
    out["frames"] = rates.rate(f"{d.id}/frames", d.image.frames)
    out.update(image_figures(d, rates))
    return out


def image_figures(d: DroneView, rates: RateMeter) -> dict[str, float]:
    """whole_fps, fresh_pct (strips that arrived, windowed), oldest_ms (oldest strip of the latest picture)."""
    k = d.frames
    fresh = rates.rate(f"{d.id}/strips_fresh", k.strips_fresh)
    expected = rates.rate(f"{d.id}/strips_expected", k.strips_expected)
    pct = 100.0 * fresh / expected if expected > 0 else float("nan")   # NaN stays NaN: nothing to say yet
    return {"whole_fps": rates.rate(f"{d.id}/whole", k.complete), "fresh_pct": min(pct, 100.0),
            "oldest_ms": k.oldest_strip_age_ms}


def _pct(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:5.1f}"


def render(gcs: Gcs, rates: RateMeter, title: str = "zenoh-robot GCS", details: str | None = None) -> Group:
    """One table, one title: a row per drone; ``details`` adds that drone's stream table."""
    drones = Table(title=f"{title}: {len(gcs.drones)} drone(s)", expand=False, pad_edge=False)
    for col in ("drone", "mode", "arm", "position (NED m)", "batt", "link", "offboard", "control",
                "sp Hz", "state Hz", "sensor Hz (PX4)", "img fps", "whole fps", "fresh %", "oldest ms", "failsafe"):
        drones.add_column(col, no_wrap=True, justify="right" if any(u in col for u in ("Hz", "fps", "%", "ms"))
                          else "left")
    shown = None
    for d in sorted(gcs.drones.values(), key=lambda d: d.id):
        f = drone_figures(d, rates)
        _drone_row(drones, d, f)
        if d.id == details:
            shown = d
    parts: list[Table] = [drones]
    if shown is not None:
        parts.append(stream_table(shown, rates))
    elif details:
        drones.caption = f"--details {details}: no such drone yet"
    return Group(*parts)


def stream_table(d: DroneView, rates: RateMeter) -> Table:
    t = Table(title=f"{d.id}: streams", expand=False)
    for col in ("stream", "rate Hz", "age avg ms", "age p99 ms", "period max ms", "received", "lost %"):
        t.add_column(col, justify="left" if col == "stream" else "right")
    for name, rec in d.streams.items():
        s = rec.summary()
        lost_pct = d.lost_pct(name)
        lost = "-" if math.isnan(lost_pct) else f"{lost_pct:.1f}"
        t.add_row(name, _hz(rates.rate(f"{d.id}/{name}", len(rec))), _ms(s.age_avg_ms), _ms(s.age_p99_ms),
                  _ms(s.period_max_ms), str(s.received), lost)
    t.add_row("setpoint (sent)", _hz(rates.rate(f"{d.id}/setpoint", d.setpoints_sent)), "", "", "",
              str(d.setpoints_sent), "")
    k = d.frames
    f = image_figures(d, rates)
    t.add_row("frames", _hz(rates.rate(f"{d.id}/frames", d.image.frames)), _ms(d.image.last_age_ms), "", "",
              f"{k.complete}/{k.frames} whole", f"decoded {k.decoded} ({k.decode_s * 1e3:.0f} ms CPU)")
    t.add_row("whole fresh frames", _hz(f["whole_fps"]), "", "", "", f"{k.patched} patched", "")
    total = f"{100.0 * k.strips_fresh / k.strips_expected:.1f} % overall" if k.strips_expected else ""
    t.add_row("fresh strips %", _pct(f["fresh_pct"]), "", "", "", f"{k.strips_fresh}/{k.strips_expected}", total)
    t.add_row("oldest strip shown", "", _ms(f["oldest_ms"]), "", "", "", "")
    return t


def _drone_row(table: Table, d: DroneView, f: dict[str, float]) -> None:
    s = d.state
    if s is None:
        table.add_row(d.id, "?", "", "", "", "waiting", "", "", _hz(f["setpoint"]), "", "", "", "", "", "", "")
        return
    pos = ",".join(f"{v:5.1f}" for v in s.position)
    batt = "-" if math.isnan(s.battery_remaining) else f"{s.battery_remaining * 100:3.0f}%"
    link = ("ok" if d.link_age < 2.0 else f"silent {d.link_age:.0f}s") if s.connected else "PX4 DOWN"
    if d.under_attack:      # the drone refuses forged or replayed sealed samples: someone is trying
        link = f"ATTACK ({s.link_refused} refused)"
    control = "this GCS" if d.in_control else (s.controller or "none")
    table.add_row(d.id, s.mode, "yes" if s.armed else "no", pos, batt, link, s.offboard_state, control[:16],
                  _hz(f["setpoint"]), _hz(f["state"]), sensor_rate(s, f["sensor"]), _hz(f["frames"]),
                  _hz(f["whole_fps"]), _pct(f["fresh_pct"]), _ms(f["oldest_ms"]),
                  (s.failsafe or (d.failures[-1] if d.failures else ""))[:30])


def sensor_rate(s: VehicleState, here: float = math.nan) -> str:
    """Rate received here (PX4's delivered rate), flagged LOW below 90 % of the rate asked of PX4."""
    got, want = s.sensor_rate_hz, s.sensor_rate_requested_hz
    px4 = "" if math.isnan(got) else f" ({got:.0f})"
    flag = " LOW" if not math.isnan(want) and not math.isnan(here) and here < 0.9 * want else ""
    return f"{_hz(here).strip()}{px4}{flag}"


def plain_lines(gcs: Gcs, rates: RateMeter) -> list[str]:
    """One short line per drone, for a pipe or a log file."""
    lines = []
    for d in sorted(gcs.drones.values(), key=lambda d: d.id):
        f = drone_figures(d, rates)
        s = d.state
        head = f"{d.id}: waiting for state" if s is None else (
            f"{d.id}: {s.mode} {'armed' if s.armed else 'disarmed'} pos "
            f"{','.join(f'{v:.1f}' for v in s.position)} offboard {s.offboard_state or '-'} "
            f"control {'this GCS' if d.in_control else (s.controller or 'none')}")
        parts = [head, f"setpoints {_hz(f['setpoint']).strip()} Hz"]
        if not math.isnan(f["sensor"]):
            parts.append(f"sensor {f['sensor']:.0f} Hz")
        if not math.isnan(f["frames"]) and d.image.frames:
            img = f"images {f['frames']:.1f} fps"
            if not math.isnan(f["whole_fps"]):
                img += f" (whole {f['whole_fps']:.1f}"
                img += f", fresh strips {f['fresh_pct']:.0f} %)" if not math.isnan(f["fresh_pct"]) else ")"
            if not math.isnan(f["oldest_ms"]):
                img += f" oldest strip {f['oldest_ms']:.0f} ms"
            parts.append(img)
        if s is not None and s.failsafe:
            parts.append(f"FAILSAFE {s.failsafe}")
        if s is not None and d.under_attack:
            parts.append(f"UNDER ATTACK: {s.link_refused} sealed samples refused (see its link_refused events)")
        lines.append(", ".join(parts))
    return lines
