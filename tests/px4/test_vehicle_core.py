"""One ``VehicleCore`` under both links to PX4: the cache, listeners, waiting, events, counters and
the heartbeat/watchdog state machine are written once and behave alike over MAVLink (real UDP bytes
from px4_link.sim) and over PX4's Zenoh module (real Zenoh sessions to px4_zenoh.sim)."""
from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from typing import Any

import pytest
from conftest import wait_for
from px4_helpers import FAST_PARAMS

from px4_link import LocalPosition, Px4Link, Telemetry
from px4_link.core import LinkCore
from px4_link.sim import Simulator
from px4_link.telemetry_service import TelemetryView
from px4_link.vehicle import VehicleLinkBase
from px4_link.vehicle_core import VehicleCore
from px4_zenoh import Px4ZenohLink
from px4_zenoh.core import ZenohCore
from px4_zenoh.services import ZenohTelemetry
from px4_zenoh.session import Px4Endpoint, free_tcp_endpoint
from px4_zenoh.sim import ZenohSimulator

SHARED_CORE = {"latest", "wait_sample", "add_sample_listener", "remove_sample_listener", "wait_until", "notify",
               "count", "emit", "safe_call", "add_event_listener", "send_command", "cancel_command", "start", "stop",
               "add_mode_hook", "add_periodic", "connected", "state", "_tx_loop", "_on_vehicle_heartbeat",
               "_set_landed_state", "_disconnect", "_on_command_ack"}
SHARED_LINK = {"start", "close", "__enter__", "__exit__", "connected", "state", "mode", "armed", "system_id",
               "wait_connected", "wait_until", "add_event_listener", "cancel_command", "send_command"}
SHARED_TELEMETRY = {"state", "latest", "wait", "add_listener", "remove_listener", "rate_hz"}
HEARTBEAT_TIMEOUT = 1.0


def test_the_two_backends_write_the_shared_part_once() -> None:
    for core in (LinkCore, ZenohCore):
        assert issubclass(core, VehicleCore) and not SHARED_CORE & set(vars(core)), core
    for link in (Px4Link, Px4ZenohLink):
        assert issubclass(link, VehicleLinkBase) and not SHARED_LINK & set(vars(link)), link
    for telemetry in (Telemetry, ZenohTelemetry):
        assert issubclass(telemetry, TelemetryView) and not SHARED_TELEMETRY & set(vars(telemetry)), telemetry


@contextlib.contextmanager
def _link(backend: str, events: list[tuple[str, dict[str, Any]]]) -> Iterator[tuple[Any, Any]]:
    def on_event(name: str, details: dict[str, Any]) -> None:
        events.append((name, details))

    if backend == "mavlink":
        with Px4Link("udpin:127.0.0.1:0", on_event=on_event, heartbeat_timeout=HEARTBEAT_TIMEOUT) as link:
            sim: Any = Simulator(1, port=0, target_port=link.local_port, params=FAST_PARAMS, seed=1).start()
            try:
                yield link, sim
            finally:
                sim.stop()
    else:
        ep = free_tcp_endpoint()
        with Px4ZenohLink(Px4Endpoint("router", ep), on_event=on_event,
                          heartbeat_timeout=HEARTBEAT_TIMEOUT) as zlink:
            sim = ZenohSimulator(connect=ep, sysid=1, params=FAST_PARAMS, seed=1).start()
            try:
                yield zlink, sim
            finally:
                sim.stop()


def _stat(link: Any, key: str) -> int:
    stats = link.stats
    return int(stats[key] if isinstance(stats, dict) else getattr(stats, key))


@pytest.mark.parametrize("backend", ["mavlink", "zenoh"])
def test_cache_listeners_callback_errors_and_watchdog_alike(backend: str, caplog: pytest.LogCaptureFixture) -> None:
    tag = "px4_link" if backend == "mavlink" else "px4_zenoh"
    caplog.set_level(logging.ERROR)
    events: list[tuple[str, dict[str, Any]]] = []
    got: list[LocalPosition] = []

    def broken(_sample: object) -> None:
        raise ValueError("a listener's bug")

    with _link(backend, events) as (link, sim):
        assert link.wait_connected(10.0)
        link.telemetry.add_listener(got.append, LocalPosition)
        link.telemetry.add_listener(broken, LocalPosition)
        fresh = link.telemetry.wait(LocalPosition, 5.0)
        assert fresh is not None and link.telemetry.latest(LocalPosition) is not None
        assert wait_for(lambda: _stat(link, "callback_errors") >= 2, 5.0)
        assert got and all(isinstance(s, LocalPosition) for s in got)   # the broken one stops nobody
        link.telemetry.remove_listener(broken)
        link.telemetry.remove_listener(got.append)
        # (over Zenoh vehicle_land_detected may come before the first vehicle_status: landed_changed first)
        assert [d["reconnect"] for n, d in events if n == "connected"] == [False], events
        assert _stat(link, "heartbeats_received") >= 1
        sim.stop()   # the vehicle goes silent
        assert link.wait_until(lambda: not link.connected, 10.0)
        assert wait_for(lambda: any(n == "disconnected" for n, _ in events), 2.0)
        assert _stat(link, "disconnects") == 1
    gone = next(d for n, d in events if n == "disconnected")
    assert gone["system_id"] == 1 and gone["silent_s"] >= 0.0
    # Over MAVLink only the watchdog can tell; over Zenoh PX4's tokens going away (or the watchdog) says why.
    assert ("why" in gone) is (backend == "zenoh")
    if backend == "mavlink":
        assert gone["silent_s"] > HEARTBEAT_TIMEOUT
    assert any(r.getMessage().startswith(f"{tag} callback") and "broken" in r.getMessage() for r in caplog.records)
