"""How often a service call re-sends its request, and how many spread copies its reply gets.

A call over a lossy best-effort link is answered once one copy of the request crosses and one
copy of the reply to it comes back. Zenoh batches what is written within ~1 ms into one datagram,
so copies sent back to back share a packet and are lost together: every copy here leaves on its
own (request copies ``step_s`` apart, reply copies :data:`REPLY_SPACING_S` apart).

With loss ``p`` each way (the measured loss plus a margin, :data:`ASSUMED_LOSS` when nothing is
measured), one request copy is answered with ``q = (1 - p) * (1 - p ** k)`` (``k`` reply copies);
``n`` request copies within the deadline all fail with ``(1 - q) ** n``. The plan picks ``k`` so
that all of one reply's copies are lost at most :data:`REPLY_MISS` of the time, then the step so
that ``(1 - q) ** n <= MISS`` over the deadline's window, clamped to [MIN_STEP_S, MAX_STEP_S]:
at most ``window / MIN_STEP_S`` (~180 in 2 s) request copies per call, at most
:data:`MAX_REPLY_COPIES` reply copies per request copy that arrives. A call stops re-sending as
soon as a reply arrives, so on a clean link a call costs one request and ``k`` reply copies.

Without a measurement the plan also *escalates*: each unanswered request copy is evidence of a
worse link, so the gaps shrink (``step / (1 + i / 4)`` after ``i`` copies, never under
MIN_STEP_S): at 50 % loss a call is answered before this matters, at 90 % the ~150 copies of
2 s answer it >= 99 % of the time (a fixed 50 ms step: ~72 %). With a measured loss the step is
already sized for it and does not escalate (no reply on a clean link means a slow or absent
server, which more copies would not help).
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

ASSUMED_LOSS = 0.5       # no measurement (no LossMonitor adapting the node): size for 50 % each way
MARGIN = 0.05            # the measured loss is noisy: plan for a little worse
MAX_LOSS = 0.97
MISS = 1e-3              # target: a call unanswered within its deadline at most this often
REPLY_MISS = 0.1         # ... and all copies of one reply lost at most this often
MIN_STEP_S = 0.01        # never more than 100 request copies a second per call
MAX_STEP_S = 0.05        # the first retry comes within 50 ms even on a clean link
MAX_REPLY_COPIES = 16
REPLY_SPACING_S = 0.005  # > Zenoh's ~1 ms batching: each reply copy in its own datagram
REPLY_COPIES_KEY = "rc"  # request envelope extra: how many reply copies the client asks for


@dataclass(frozen=True)
class CallPlan:
    step_s: float          # gap between request copies while no reply came
    reply_copies: int      # copies of the reply per request copy that arrives
    loss: float            # the loss the plan was sized for (measured + margin)
    escalate: bool = False  # no measurement: shrink the gaps while no reply comes

    def delays(self) -> Iterator[float]:
        i = 0
        while True:
            i += 1
            yield max(MIN_STEP_S, self.step_s / (1 + i / 4)) if self.escalate else self.step_s

    def copies_within(self, deadline_s: float) -> int:
        """Request copies sent within the deadline's window if no reply comes."""
        t, n, gaps = 0.0, 1, self.delays()
        while True:
            t += next(gaps)
            if t > window(deadline_s):
                return n
            n += 1

    def answered(self, loss: float, deadline_s: float) -> float:
        """Predicted P(answered within ``deadline_s``) at independent loss ``loss`` each way."""
        q = (1 - loss) * (1 - loss ** self.reply_copies)
        return float(1 - (1 - q) ** self.copies_within(deadline_s))


def window(deadline_s: float) -> float:
    """The part of a deadline in which a request copy can still be answered (a reply needs a trip)."""
    return max(0.0, 0.9 * deadline_s)


def planned_loss(loss: float) -> float:
    base = loss if math.isfinite(loss) else ASSUMED_LOSS
    return min(MAX_LOSS, max(0.0, base) + MARGIN)


def reply_copies_for(loss: float) -> int:
    """Copies of a reply so that all are lost at most REPLY_MISS of the time (at most MAX_REPLY_COPIES)."""
    p = planned_loss(loss)
    need = math.ceil(math.log(REPLY_MISS) / math.log(p)) if p > 0 else 1
    return max(1, min(MAX_REPLY_COPIES, need))


def call_plan(loss: float, deadline_s: float) -> CallPlan:
    """The plan for one call with deadline ``deadline_s`` at measured loss ``loss`` (NaN: unknown)."""
    p = planned_loss(loss)
    k = reply_copies_for(loss)
    q = (1 - p) * (1 - p ** k)
    n = math.ceil(math.log(MISS) / math.log(1 - q)) if 0 < q < 1 else 1
    step = min(MAX_STEP_S, max(MIN_STEP_S, window(deadline_s) / max(1, n)))
    return CallPlan(step, k, p, escalate=not math.isfinite(loss))


def requested_reply_copies(value: object) -> int | None:
    """A request's ``rc`` field if it is valid (an int 1..MAX_REPLY_COPIES), else None (ignored)."""
    if type(value) is int and 1 <= value <= MAX_REPLY_COPIES:
        return value
    return None
