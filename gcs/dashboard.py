"""A live terminal dashboard (rich): per drone its state, per stream its age, period and rate."""
from __future__ import annotations

import math
import time

from rich.console import Group
from rich.table import Table

from companion.interface import VehicleState

from .app import DroneLink, Gcs


def _ms(v: float) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:7.1f}"


class RateMeter:
    """Rate over the last refresh, from a cumulative counter."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, int]] = {}

    def rate(self, key: str, count: int) -> float:
        now = time.monotonic()
        t, c = self._last.get(key, (now, count))
        self._last[key] = (now, count)
        return (count - c) / (now - t) if now > t else float("nan")


def render(gcs: Gcs, rates: RateMeter, title: str = "zenoh-robot GCS") -> Group:
    drones = Table(title=title, expand=True)
    for col in ("drone", "mode", "armed", "landed", "position (NED m)", "battery", "PX4", "link", "offboard",
                "control", "sensor Hz (asked)", "failsafe"):
        drones.add_column(col)
    streams = Table(expand=True)
    for col in ("drone", "stream", "rate Hz", "age avg ms", "age p99 ms", "period avg ms", "period max ms",
                "received", "lost %"):
        streams.add_column(col, justify="right" if col not in ("drone", "stream") else "left")
    for d in sorted(gcs.drones.values(), key=lambda d: d.id):
        _drone_row(drones, d)
        drones_sent = {"setpoint": d.setpoints_sent}
        for name, rec in d.streams.items():
            s = rec.summary()
            lost = "-" if math.isnan(rec.lost_pct()) else f"{rec.lost_pct():.1f}"
            streams.add_row(d.id, name, f"{rates.rate(d.id + name, s.received):6.1f}", _ms(s.age_avg_ms),
                            _ms(s.age_p99_ms), _ms(s.period_avg_ms), _ms(s.period_max_ms), str(s.received), lost)
        streams.add_row(d.id, "setpoint (sent)", f"{rates.rate(d.id + 'sp', drones_sent['setpoint']):6.1f}",
                        "", "", "", "", str(d.setpoints_sent), "")
        streams.add_row(d.id, "frames shown", f"{rates.rate(d.id + 'frames', d.image.frames):6.1f}",
                        _ms(d.image.last_age_ms), "", "", "", f"{d.image.complete}/{d.image.frames} whole", "")
    return Group(drones, streams)


def _drone_row(table: Table, d: DroneLink) -> None:
    s = d.state
    if s is None:
        table.add_row(d.id, "?", "", "", "", "", "", "waiting", "", "", "", "")
        return
    pos = ", ".join(f"{v:6.1f}" for v in s.position)
    batt = "-" if math.isnan(s.battery_remaining) else f"{s.battery_remaining * 100:3.0f}%"
    link = "ok" if d.link_age < 2.0 else f"silent {d.link_age:.0f}s"
    control = "this GCS" if d.in_control else (s.controller or "none")
    table.add_row(d.id, s.mode, "yes" if s.armed else "no", "yes" if s.landed else "no", pos, batt,
                  "up" if s.connected else "DOWN", link, s.offboard_state, control, sensor_rate(s),
                  s.failsafe or (d.failures[-1] if d.failures else ""))


def sensor_rate(s: VehicleState) -> str:
    """Delivered (requested) HIGHRES_IMU rate, flagged LOW below 90 % of the request."""
    got, want = s.sensor_rate_hz, s.sensor_rate_requested_hz
    if math.isnan(got) or math.isnan(want):
        return "-"
    flag = " LOW" if got < 0.9 * want else ""
    return f"{got:.0f} ({want:.0f}){flag}"
