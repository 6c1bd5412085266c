"""The one thread where the companion's PX4 commands run.

PX4 commands wait for an ACK (up to seconds): never on the executor's threads, nor on Zenoh's or
px4_link's. One worker: lifecycle transitions and commands run in order, never concurrently.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from px4_link.commands import CommandError
from px4_link.targets import TargetRefused

from .events import EventReporter

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had

# A failure of these background jobs is a failed failsafe, not a lifecycle note.
FAILSAFE_JOBS = ("park", "offboard_lost")


class Px4Worker:
    def __init__(self, events: EventReporter) -> None:
        self._events = events
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="px4-cmd")

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        return self._pool.submit(fn, *args)

    def submit_guarded(self, what: str, fn: Callable[[], Any]) -> None:
        """Run ``fn`` in order with the rest; nobody waits for it, so a failure is logged and reported."""
        self._pool.submit(self._guarded, what, fn)

    def _guarded(self, what: str, fn: Callable[[], Any]) -> None:
        try:
            fn()
        except (CommandError, TargetRefused, RuntimeError) as exc:
            log.error("%s: %s", what, exc)
            self._events.event("failsafe_failed" if what in FAILSAFE_JOBS else "lifecycle",
                               f"{what} failed: {exc}", "")

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
