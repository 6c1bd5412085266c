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
from rich.text import Text

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


# The drone table's columns, most needed for flying first: at 80 columns the first seven fit (the
# drone, its mode, armed, altitude, link, the setpoints this GCS sends, battery); wider terminals add
# the rest in this order, and the table always shows them in ``_ORDER``.
_PRIORITY = ("drone", "mode", "arm", "alt m", "link", "sp Hz", "batt", "offboard", "control", "failsafe",
             "state Hz", "sensor Hz (PX4)", "position (NED m)", "img fps", "whole fps", "fresh %", "oldest ms")
_ORDER = ("drone", "mode", "arm", "alt m", "position (NED m)", "batt", "link", "offboard", "control", "sp Hz",
          "state Hz", "sensor Hz (PX4)", "img fps", "whole fps", "fresh %", "oldest ms", "failsafe")
_RIGHT = ("Hz", "fps", "%", "ms", "alt m", "batt")
EVENT_LINES = 3          # the latest events and mission steps shown under the table


def render(gcs: Gcs, rates: RateMeter, title: str = "zenoh-robot GCS", details: str | None = None,
           width: int = 200, progress: list[str] | None = None) -> Group:
    """One table, one title: a row per drone, with as many columns as ``width`` holds (most needed
    first, ``_PRIORITY``); the mission's progress and the latest events under it; ``details`` adds that
    drone's stream table."""
    views = sorted(gcs.drones.values(), key=lambda d: d.id)
    rows = [_drone_cells(d, drone_figures(d, rates)) for d in views]
    columns = fit_columns(rows, width)
    drones = Table(title=f"{title}: {len(gcs.drones)} drone(s)", expand=False, pad_edge=False)
    for col in columns:
        drones.add_column(col, no_wrap=True, overflow="ellipsis",
                          justify="right" if any(u in col for u in _RIGHT) else "left")
    for cells in rows:
        drones.add_row(*(cells.get(col, "") for col in columns))
    shown = next((d for d in views if d.id == details), None)
    parts: list[Table | Text] = [drones]
    # Both kinds of line begin with their HH:MM:SS: one time order, newest last.
    lines = sorted([*(progress or [])[-EVENT_LINES:], *latest_events(views, EVENT_LINES)], key=lambda ln: ln[:8])
    for line in lines[-EVENT_LINES * 2:]:
        parts.append(Text(line[:max(20, width - 1)], no_wrap=True, overflow="ellipsis"))
    if shown is not None:
        parts.append(stream_table(shown, rates))
    elif details:
        drones.caption = f"--details {details}: no such drone yet"
    return Group(*parts)


def fit_columns(rows: list[dict[str, str]], width: int) -> list[str]:
    """The columns that fit in ``width`` characters, most needed first, shown in ``_ORDER``: a column
    takes its widest cell (or header) plus its border and padding (3 characters)."""
    taken, used = set(), 1
    for col in _PRIORITY:
        need = max([len(col), *(len(r.get(col, "")) for r in rows)]) + 3
        if col == "drone" or used + need <= width:
            taken.add(col)
            used += need
        elif col in _PRIORITY[:3]:     # drone, mode, armed: never dropped, cut to fit instead
            taken.add(col)
    return [c for c in _ORDER if c in taken]


def latest_events(views: list[DroneView], n: int) -> list[str]:
    """The ``n`` newest events the drones reported, newest last: ``uav1 lifecycle: ...``."""
    events = [(e.header.stamp if e.header is not None else 0, d.id, e) for d in views for e in d.events[-n:]]
    events.sort(key=lambda t: t[0])
    return [f"{time.strftime('%H:%M:%S', time.localtime(ts / 1e9)) if ts else '--:--:--'} {did} {e.kind}: "
            f"{e.detail}" for ts, did, e in events[-n:]]


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


def _drone_cells(d: DroneView, f: dict[str, float]) -> dict[str, str]:
    s = d.state
    if s is None:
        return {"drone": d.id, "mode": "?", "link": "waiting", "sp Hz": _hz(f["setpoint"]),
                "failsafe": _first_alert(d)[:30]}
    link = ("ok" if d.link_age < 2.0 else f"silent {d.link_age:.0f}s") if s.connected else "PX4 DOWN"
    if d.under_attack:      # the drone refuses forged or replayed sealed samples: someone is trying
        link = f"ATTACK ({s.link_refused} refused)"
    alt = -s.position[2]
    return {"drone": d.id, "mode": s.mode_label, "arm": "yes" if s.armed else "no",
            "alt m": "-" if math.isnan(alt) else f"{alt:5.1f}",
            "position (NED m)": ",".join(f"{v:5.1f}" for v in s.position),
            "batt": "-" if math.isnan(s.battery_remaining) else f"{s.battery_remaining * 100:3.0f}%",
            "link": link, "offboard": s.offboard_state,
            "control": ("this GCS" if d.in_control else (s.controller or "none"))[:16],
            "sp Hz": _hz(f["setpoint"]), "state Hz": _hz(f["state"]), "sensor Hz (PX4)": sensor_rate(s, f["sensor"]),
            "img fps": _hz(f["frames"]), "whole fps": _hz(f["whole_fps"]), "fresh %": _pct(f["fresh_pct"]),
            "oldest ms": _ms(f["oldest_ms"]).strip(),
            "failsafe": (s.failsafe or _first_alert(d) or (d.failures[-1] if d.failures else ""))[:30]}


def _first_alert(d: DroneView) -> str:
    """A standing problem (gcs/alerts.py) without the drone's name, which the row already shows."""
    text = next(iter(d.alerts.now.values()), "")
    return text.removeprefix(f"{d.id} ")


def sensor_rate(s: VehicleState, here: float = math.nan) -> str:
    """Rate received here (PX4's delivered rate), flagged LOW below 90 % of what PX4 delivers: the link's
    loss, not PX4's own ceiling (PX4, like its simulator, gives ~120 Hz of HIGHRES_IMU when 200 are asked)."""
    got = s.sensor_rate_hz
    px4 = "" if math.isnan(got) else f" ({got:.0f})"
    flag = " LOW" if not math.isnan(got) and not math.isnan(here) and here < 0.9 * got else ""
    return f"{_hz(here).strip()}{px4}{flag}"


def plain_lines(gcs: Gcs, rates: RateMeter) -> list[str]:
    """One short line per drone, for a pipe or a log file."""
    if not gcs.drones:
        return ["no drone heard yet: waiting for <id>/state (is a companion running, in this domain?)"]
    lines = []
    for d in sorted(gcs.drones.values(), key=lambda d: d.id):
        f = drone_figures(d, rates)
        s = d.state
        head = f"{d.id}: waiting for state" if s is None else (
            f"{d.id}: {s.mode_label} {'armed' if s.armed else 'disarmed'} pos "
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
        parts.extend(d.alerts.now.values())    # "uav3 sensor: publisher seen, 0 samples in 5 s", two companions
        if s is not None and d.under_attack:
            parts.append(f"UNDER ATTACK: {s.link_refused} sealed samples refused (see its link_refused events)")
        lines.append(", ".join(parts))
    return lines
