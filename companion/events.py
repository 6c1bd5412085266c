"""What the companion tells the GCS it saw and did: FailsafeEvents on ``<id>/events``, logged too.

Threads: any. ``Publisher.publish`` is thread safe; the list of kinds sent is only appended
to and trimmed (the summary reads it at the end).
"""
from __future__ import annotations

import logging
from typing import Any

from drone_contract.messages import FailsafeEvent
from zenoh_robot.msgs import Header
from zenoh_robot.publisher import PublisherClosed
from zenoh_robot.ratelimit import RateLimiter

log = logging.getLogger("companion")   # the app's logger: event lines keep the name they always had
# Kinds that every flight sends on its way (the lifecycle's steps, setpoints before offboard_start, what PX4's
# sensor rate is): logged at INFO, still published to the GCS like every event.
ROUTINE = frozenset({"lifecycle", "setpoint_ignored", "sensor_rate_low"})
# Kinds that mean this process should not be flying as it is (a second companion with its id): errors.
SEVERE = frozenset({"duplicate_id"})


class EventReporter:
    KEPT = 200   # kinds kept for the summary

    def __init__(self, publisher: Any, report_interval_s: float) -> None:
        self.publisher = publisher
        self.sent: list[str] = []
        self.limiter = RateLimiter(interval=report_interval_s)

    def event(self, kind: str, detail: str, action: str = "", client_id: str = "", count: int = 0) -> None:
        # Expected steps of a normal flight are information; what the operator must look at is a warning.
        level = logging.INFO if kind in ROUTINE else logging.ERROR if kind in SEVERE else logging.WARNING
        log.log(level, "%s%s: %s -> %s", kind, f" [{client_id}]" if client_id else "", detail, action or "no action")
        self.sent.append(kind)
        del self.sent[:-self.KEPT]
        try:
            self.publisher.publish(FailsafeEvent(Header.now(), kind, detail, action, client_id, count))
        except PublisherClosed:
            pass

    def refused(self, kind: str, client_id: str, reason: str, detail: str) -> None:
        """Count always; publish and log the first and then once per interval per (kind, client, reason)."""
        count = self.limiter.hit(kind, client_id, reason)
        if count:
            self.event(kind, detail, "refused", client_id, count)
