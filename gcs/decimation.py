"""The sensor decimated at its source when this GCS cannot keep up (issue #42: overload by priority).

gcs/shedding.py names what this GCS's own queue drops. Dropped there, a sample has still cost the drone its
publishing, the link its bytes and this GCS Zenoh's delivery of it. So when ``WINDOWS`` windows in a row of a
drone's sensor each lose at least ``SHARE`` of their samples to this GCS's queue (an overload that lasts, not
a loaded moment's stall), the GCS asks the drone for the rate it did keep up with, ``KEEP`` of it, never under
``MIN_HZ`` and at most once per ``STEP_S`` (gcs/downlink.py: the companion's live ``sensor_rate_hz``, which it
takes from the GCS in control only: a monitoring GCS's load never changes a drone's downlink). Said out loud
(the ``decimated_sensor`` alert: dashboard, status line, summary), asked again when the drone rejoins, and put
back to the drone's own rate when this GCS releases control or closes. It never raises the rate by itself: a
GCS that keeps up at the lower rate cannot know it would at the old one.

Setpoints, commands and state are never shed (the contract's order); images are left to the camera's own
priority on the drone (companion/priority.py) and the lazy receiver here.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from .shedding import Window

SHARE = 0.2      # a window losing a fifth of its samples here: overload, not a hiccup (N=5: 1-13 in 40 s)
KEEP = 0.8       # of the rate this GCS kept up with: room for the rest of its work
MIN_HZ = 10.0    # below this the sensor stream says little; the GCS sheds at its queue instead
STEP_S = 10.0    # one step per drone at most this often: the last one must take effect and be measured
WINDOWS = 2      # windows in a row over SHARE before a step


@dataclass(frozen=True)
class Step:
    rate_hz: float     # what to ask the drone for
    kept_hz: float     # what this GCS kept up with in the window
    text: str          # the alert's text


class SensorDecimation:
    """One drone's decision: ``window()`` per shedding window, ``Step`` when the drone should send less."""

    def __init__(self, drone_id: str) -> None:
        self.drone_id = drone_id
        self.next_at = -math.inf
        self.steps = 0           # asked in all (the summary's figure)
        self.last_hz = math.nan
        self._over = 0           # windows in a row over SHARE

    def on_window(self, view: Any, stream: str, w: Window) -> None:
        """SheddingWatch's window of ``view`` (a gcs.app.DroneView), on the executor: a step is asked of the
        drone through the GCS's downlink and raised on the drone's alerts."""
        downlink, s = view.gcs.downlink, view.state
        if stream != "sensor" or downlink is None or s is None or not view.gcs.config.decimate_sensor:
            return
        step = self.window(w, float(s.sensor_rate_requested_hz), view.in_control, time.monotonic())
        if step is not None:
            view.alerts.raise_("decimated_sensor", step.text)
            downlink.lower(view.id, "sensor_rate_hz", step.rate_hz, before=float(s.sensor_rate_requested_hz))

    def window(self, w: Window, asked_hz: float, in_control: bool, now: float) -> Step | None:
        """``w``: this window at the GCS's queue; ``asked_hz``: the drone's sensor rate now (its state's
        ``sensor_rate_requested_hz``). What the GCS kept up with is the samples it delivered (once each):
        arrivals count a sample's copies too (the resilient profile sends each sensor sample twice)."""
        received, dropped, seconds = w.received, w.dropped, w.seconds
        self._over = self._over + 1 if received > 0 and dropped >= SHARE * received else 0
        if not in_control or self._over < WINDOWS or now < self.next_at or not seconds > 0:
            return None
        kept = w.delivered / seconds
        rate = float(max(MIN_HZ, math.floor(KEEP * kept)))
        if not (math.isfinite(asked_hz) and rate < 0.9 * asked_hz):
            return None      # at the floor already, or the drone sends little enough
        self.next_at = now + STEP_S
        self.steps += 1
        self.last_hz = rate
        text = (f"{self.drone_id} sensor: this GCS delivered {kept:.0f} samples/s and its queue dropped {dropped:,} "
                f"of {received:,} arrivals in {seconds:.0f} s; asked the drone for {rate:g} Hz (was {asked_hz:g}) "
                "until this GCS closes")
        return Step(rate, kept, text)
