"""Streams at a rate and the statistics windows a subscription publishes: shared by the topic statistics tests."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from conftest import wait_for

from zenoh_robot.msgs import TopicStatistics


class Stream:
    """Publishes ``make()`` at ``rate_hz`` from a thread until stop()."""

    def __init__(self, pub: Any, make: Callable[[], Any], rate_hz: float) -> None:
        self.pub, self.make, self.period = pub, make, 1.0 / rate_hz
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        next_at = time.monotonic()
        while not self._stop.is_set():
            self.pub.publish(self.make())
            self.sent += 1
            next_at += self.period   # deadline-based, so scheduling jitter does not lower the rate
            self._stop.wait(max(0.0, next_at - time.monotonic()))

    def __enter__(self) -> "Stream":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def collect_windows(sub: Any) -> list[TopicStatistics]:
    got: list[TopicStatistics] = []
    sub.statistics.listeners.append(got.append)
    return got


def matched(pub: Any, sub: Any) -> None:
    assert wait_for(lambda: pub.get_subscription_count() >= 1 and sub.get_publisher_count() >= 1, 5.0), \
        "publisher and subscription never matched"
