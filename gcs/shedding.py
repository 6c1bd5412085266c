"""What the GCS itself sheds, named: a drone's stream whose samples this GCS's own queue dropped (issue #42).

A subscription's queue is bounded (KEEP_LAST depth, bytes): when the executor falls behind, the oldest
samples go and ``counters.dropped`` counts them. Silently, that looks like a drone that sends less. Every
``PERIOD_S`` the GCS compares each stream's counters with the last look; a stream that lost samples to
its own queue raises ``shedding_<stream>`` on the drone's alerts (the dashboard, the status line, the
summary: "uav3 sensor: this GCS dropped 812 of 1,000 samples in 5 s ..."), cleared when a window drops
none. The order is the contract's: setpoint and command are this GCS's own sends (never shed here),
state keeps depth 1 by design (newest wins: not counted as shedding), sensor and image are what a
loaded GCS gives up first.

Runs on the node's executor (a timer); reads counters written under the subscriptions' locks as plain
ints (a racy read is off by one sample at most, never torn).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .alerts import Alerts

PERIOD_S = 5.0
# state is KEEP_LAST(1): a newer state replacing one not yet shown is the design, not overload.
WATCHED = ("sensor", "image")


@dataclass
class _Seen:
    received: int = 0
    dropped: int = 0
    delivered: int = 0
    at: float = 0.0      # monotonic time of the look


@dataclass(frozen=True)
class Window:
    """One window of a stream at this GCS: arrivals (a sample's copies each count), those its queue dropped,
    the samples delivered (once each), over ``seconds`` of the clock (a starved executor looks late)."""
    received: int
    dropped: int
    delivered: int
    seconds: float


def _seen(c: Any) -> _Seen:
    return _Seen(int(c.received), int(c.dropped), int(getattr(c, "delivered", 0)), time.monotonic())


class SheddingWatch:
    def __init__(self, alerts: Alerts, on_window: Callable[[str, Window], None] | None = None) -> None:
        self._alerts = alerts
        self._on_window = on_window     # every window of every stream: decimation.py
        self._subs: dict[str, Any] = {}
        self._last: dict[str, _Seen] = {}
        self.windows_shedding: dict[str, int] = {}   # per stream: windows with drops (the summary's figure)
        self.dropped: dict[str, int] = {}            # per stream: samples this GCS dropped in all
        self._raised: set[str] = set()

    def watch(self, stream: str, subscription: Any) -> None:
        """Follow ``subscription`` (anything with ``counters.received`` and ``counters.dropped``)."""
        if subscription is None or stream not in WATCHED:
            return
        self._subs[stream] = subscription
        c = subscription.counters
        self._last[stream] = _seen(c)

    def check(self) -> None:
        """One window (the executor's timer, every PERIOD_S)."""
        for stream, sub in self._subs.items():
            c = sub.counters
            now = _seen(c)
            last = self._last[stream]
            self._last[stream] = now
            received, dropped = now.received - last.received, now.dropped - last.dropped
            if self._on_window is not None:
                self._on_window(stream, Window(received, dropped, now.delivered - last.delivered, now.at - last.at))
            if dropped > 0:
                self.windows_shedding[stream] = self.windows_shedding.get(stream, 0) + 1
                self.dropped[stream] = self.dropped.get(stream, 0) + dropped
                if stream not in self._raised:   # raised once per episode: one warning, not one per window
                    self._raised.add(stream)
                    # The share is of what reached this process: the rest never arrived (network loss).
                    self._alerts.raise_(f"shedding_{stream}",
                                        f"{self._alerts.drone_id} {stream}: this GCS drops samples ({dropped:,} of "
                                        f"{received:,} in {PERIOD_S:g} s): its queue is full, it cannot keep up; "
                                        "the newest are kept")
            elif stream in self._raised:
                self._raised.discard(stream)
                self._alerts.clear(f"shedding_{stream}", f"{self._alerts.drone_id} {stream}: no longer dropping "
                                                         f"samples ({self.dropped[stream]:,} dropped in all)")
