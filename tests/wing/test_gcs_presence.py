"""A GCS in control keeps control while it runs, even where its liveliness token never reaches the drone.

Zenoh's UDP multicast transport carries no liveliness, so a companion there hears of its GCS only through
what the GCS sends. Once a landing has begun the GCS streams no setpoints; before the presence stream the
companion released it ("liveliness lost") one lease later, while that GCS was still waiting for the landing.

Real processes and sessions: a router session, a companion process (built-in simulator, a 2 s control
lease), and the GCS in this process with its liveliness token withdrawn (as on a multicast session).
"""
from __future__ import annotations

import json
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from conftest import free_port, python_proc, wait_for

from drone_contract.messages import FailsafeEvent, VehicleState
from drone_contract.streams import stream_profile
from gcs.app import Gcs, GcsConfig
from zenoh_robot import Node, SessionConfig
from zenoh_robot.session_config import open_session

PROFILE = stream_profile("resilient")
LEASE_S = 2.0


@contextmanager
def drone(ns: str, tmp: Path) -> Iterator[tuple[str, list[str]]]:
    """(router endpoints, the companion's id) with one companion running on a 2 s control lease."""
    port = free_port()
    endpoints = [f"tcp/127.0.0.1:{port}", f"udp/127.0.0.1:{port}"]
    router = open_session(SessionConfig(mode="router", listen=endpoints, multicast_scouting=False,
                                        shared_memory=False))
    conf = tmp / "client.json5"
    conf.write_text(json.dumps({"mode": "client", "connect": {"endpoints": endpoints},
                                "scouting": {"multicast": {"enabled": False}},
                                "transport": {"unicast": {"max_links": 2}, "shared_memory": {"enabled": False}}}))
    drone_id = f"{ns}_1"
    proc = python_proc("-m", "companion", "--id", drone_id, "--px4", "sim", "--zenoh", str(conf),
                       "--camera", "none", "--control-lease", f"{LEASE_S:g}", "--no-topic-statistics")
    try:
        yield drone_id, endpoints
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        router.close()


def client(endpoints: list[str]) -> SessionConfig:
    return SessionConfig(mode="client", listen=[], connect=endpoints, multicast_scouting=False, shared_memory=False)


def test_a_running_gcs_keeps_control_without_its_token_and_loses_it_once_gone(ns: str, tmp_path: Path) -> None:
    with drone(ns, tmp_path) as (drone_id, endpoints), \
            Node("observer", config=client(endpoints), enable_topic_statistics=False) as observer:
        states: list[VehicleState] = []
        events: list[FailsafeEvent] = []
        q = PROFILE.qos
        observer.create_subscription(VehicleState, f"/{drone_id}/state", lambda m: states.append(m), q["state"])
        observer.create_subscription(FailsafeEvent, f"/{drone_id}/events", lambda m: events.append(m), q["events"])
        threading.Thread(target=observer.spin, daemon=True).start()
        me = f"{ns}_op"
        node = Node("gcs", config=client(endpoints), enable_topic_statistics=False)
        try:
            g = Gcs(node, GcsConfig(drones=[drone_id], profile=PROFILE, client_id=me, pattern="hover"))
            # As on a multicast session: the companion never sees this GCS's token.
            g._token.undeclare()
            g.streaming = False   # no setpoints, as once a landing has begun
            threading.Thread(target=node.spin, daemon=True).start()
            d = g.drones[drone_id]
            assert wait_for(lambda: d.state is not None and d.state.connected, 30), "no state from the companion"
            res = d.command("take_control")
            assert res.success, res.message
            assert wait_for(lambda: bool(states) and states[-1].controller == me, 5)
            # Three leases on the ground with nothing but the presence from this GCS: still in control.
            threading.Event().wait(3 * LEASE_S)
            released = [e.detail for e in events if e.kind == "control_changed" and "liveliness lost" in e.detail]
            assert not released, released
            assert states[-1].controller == me and not states[-1].armed, states[-1]
        finally:
            node.close()   # gone without release_control: a crash, a cut link
        # A gone GCS (nothing more from it) is released on the ground within a lease (and the watchdog's tick).
        assert wait_for(lambda: states[-1].controller == "", 3 * LEASE_S), states[-1].controller
        assert wait_for(lambda: any(e.kind == "control_changed" and f"{me} released: liveliness lost" in e.detail
                                    for e in events), 5), [e.detail for e in events]
