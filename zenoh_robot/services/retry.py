"""When a call re-sends its request: fixed backoff (RetryPolicy), per-call plans (AdaptiveRetry), presets.

A retry re-sends the very same bytes (one request id), so the server's idempotency cache runs
the call once however many copies arrive (the package doc has the whole contract).
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from . import call_plan as plans

if TYPE_CHECKING:
    from ..node import Node


@dataclass(frozen=True)
class RetryPolicy:
    """When a call re-sends its request (same request id) while no reply came, until its timeout.

    Gaps: ``interval_s``, then each ``multiplier`` times the previous, never over ``max_interval_s``.
    """
    interval_s: float = 0.1
    multiplier: float = 1.5
    max_interval_s: float = 1.0

    def __post_init__(self) -> None:
        if not (self.interval_s > 0 and self.multiplier >= 1.0 and self.max_interval_s >= self.interval_s):
            raise ValueError(f"RetryPolicy needs interval_s > 0, multiplier >= 1, max_interval_s >= interval_s: {self}")

    def delays(self) -> Iterator[float]:
        gap = self.interval_s
        while True:
            yield gap
            gap = min(self.max_interval_s, gap * self.multiplier)


# The multicast default. At 50 % loss each way one attempt is answered with p = 0.25, so what
# matters is attempts within the caller's deadline: 50 ms growing 10 % per try, capped at 200 ms,
# is ~17 attempts in 2 s (0.75^17 < 1 % unanswered). A command is ~100 bytes: the cost is nothing.
RESILIENT_RETRY = RetryPolicy(interval_s=0.05, multiplier=1.1, max_interval_s=0.2)
_DEFAULT: Any = object()     # "the client's own retry policy" (None means no retry)
# Unicast: queries ride a reliable link, so a retry only covers a link that broke and came back.
UNICAST_COMMAND_RETRY = RetryPolicy(interval_s=0.5, multiplier=2.0, max_interval_s=2.0)


@dataclass(frozen=True)
class AdaptiveRetry:
    """Retries sized per call from the client's loss estimate and the call's deadline (call_plan.py).

    Request copies go out every ``plan.step_s`` (10-50 ms) until a reply or the deadline; on a
    multicast session the request asks the server for ``plan.reply_copies`` spread reply copies.
    The estimate comes from ``client.set_loss`` (e.g. ``loss_monitor.adapt(client.set_loss)``);
    without one the plan is sized for 50 % loss each way.
    """

    def plan(self, loss: float, timeout: float) -> plans.CallPlan:
        return plans.call_plan(loss, timeout)


ADAPTIVE_RETRY = AdaptiveRetry()
Retry = RetryPolicy | AdaptiveRetry


def command_retry(node: "Node") -> Retry:
    """The retry policy for commands (must arrive, must run once) on any session: adaptive.

    A unicast session's link may be UDP (best effort: a lost query is gone) as well as TCP, so
    commands get the same at-least-once retries there; the server's cache keeps them run once.
    """
    return ADAPTIVE_RETRY
