"""Matched but silent: a subscription with a matched publisher that receives nothing says so.

The deadline event counts from the first sample (before it there is nothing to be late), so a
stream that never arrives at all, while its publisher is on the graph, went unreported: issue #42
saw 0 of 7,312 sensor samples reach a GCS for a whole flight with no event. A subscription whose
``SubscriptionEventCallbacks.silent_stream`` is set is watched: once a compatible publisher has
been matched for ``SILENT_PERIODS`` x its expected period (the QoS deadline, else
``Subscription.expected_period_s``; ``DEFAULT_WINDOW_S`` when neither is known) with no sample
delivered, one :class:`~zenoh_robot.events.SilentStreamInfo` (``silent`` True) is raised; the first
sample after it raises one with ``silent`` False. One event per change, never one per tick.

Threads: :meth:`SilenceWatch.check` runs on the node's QoS monitor and only compares clocks; the
subscription's hot path is untouched (it already stamps ``last_sample_mono``).
"""
from __future__ import annotations

from .events import SilentStreamInfo

SILENT_PERIODS = 5
DEFAULT_WINDOW_S = 5.0
MIN_WINDOW_S = 1.0     # a fast stream quiet for 5 of its periods (25 ms at 200 Hz) is jitter, not silence


def silence_window(expected_period_s: float | None, deadline_s: float | None) -> float:
    period = expected_period_s if expected_period_s is not None else deadline_s
    if period is None or not period > 0:
        return DEFAULT_WINDOW_S
    return max(MIN_WINDOW_S, SILENT_PERIODS * period)


class SilenceWatch:
    """One subscription's silent/recovered state (the module doc)."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.silent = False
        self.total_count = 0
        self._silent_at = 0.0

    def check(self, now: float, publishers: int, matched_at: float | None,
              last_sample: float | None) -> SilentStreamInfo | None:
        """The event to raise now, if any. ``matched_at``: when the newest publisher matched."""
        if self.silent:
            if last_sample is not None and last_sample > self._silent_at:
                self.silent = False
                return SilentStreamInfo(False, self.window_s, publishers, now - self._silent_at, self.total_count,
                                        True)
            return None
        if not publishers or matched_at is None:
            return None
        since = max(matched_at, last_sample or 0.0)
        if now - since < self.window_s:
            return None
        self.silent, self._silent_at = True, now
        self.total_count += 1
        return SilentStreamInfo(True, self.window_s, publishers, now - since, self.total_count,
                                last_sample is not None)
