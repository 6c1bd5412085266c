"""Shared helpers for the px4_link tests: simulators and links on ephemeral ports."""
from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Iterator

from conftest import python_proc, wait_for  # noqa: F401  (wait_for is re-exported for the px4 tests)
from px4_link import Px4Link
from px4_link.sim import Simulator

# Faster than PX4's defaults where only test time is at stake (climb/landing rates).
FAST_PARAMS = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.0, "MIS_TAKEOFF_ALT": 2.0}


class EventLog:
    """on_event sink that tests can query."""

    def __init__(self) -> None:
        self.events: list[tuple[float, str, dict]] = []

    def __call__(self, name: str, details: dict) -> None:
        self.events.append((time.monotonic(), name, details))

    def names(self) -> list[str]:
        return [n for _, n, _ in self.events]

    def count(self, name: str) -> int:
        return self.names().count(name)


@contextmanager
def sim_and_link(sysid: int = 1, params: dict | None = None, link_kwargs: dict | None = None,
                 sim_kwargs: dict | None = None) -> Iterator[tuple[Simulator, Px4Link, EventLog]]:
    """A simulator sending to a link bound on an ephemeral localhost port, connected."""
    events = EventLog()
    kw = {"on_event": events, **(link_kwargs or {})}
    with Px4Link("udpin:127.0.0.1:0", **kw) as link:
        with Simulator(sysid, port=0, target_port=link.local_port,
                       params={**FAST_PARAMS, **(params or {})}, seed=sysid,
                       **(sim_kwargs or {})) as sim:
            assert link.wait_connected(5.0), "link never saw the simulator's heartbeat"
            yield sim, link, events


def sim_process(sysid: int, target_port: int, *extra: str):
    """``python -m px4_link.sim`` as a real child process."""
    return python_proc("-m", "px4_link.sim", "--sysid", str(sysid), "--port", "0",
                       "--target-port", str(target_port), *extra)
