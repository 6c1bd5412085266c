"""Drone discovery (gcs/discovery.py): a namespace publishing ``<id>/state`` is a drone, for the GCS app
and for ``gcs cmd all`` alike; an id no app could use is never reported."""
from __future__ import annotations

import threading

from conftest import spinning_nodes, wait_for

from drone_contract.messages import VehicleState
from drone_contract.streams import stream_profile
from gcs.app import Gcs, GcsConfig
from gcs.discovery import discover_drones, drone_id


def test_a_drone_id_is_a_key_chunk_the_apps_can_use() -> None:
    assert drone_id("uav1/state") == "uav1"
    assert drone_id("_x9/state") == "_x9"
    assert drone_id("9uav/state") is None
    assert drone_id("uav-1/state") is None
    assert drone_id("/state") is None


def test_the_gcs_and_gcs_cmd_all_find_the_same_drones(ns: str) -> None:
    with spinning_nodes(ns) as (drone_side, ground):
        pub = drone_side.create_publisher(VehicleState, f"/{ns}d1/state", 10)
        stop = threading.Event()

        def publish() -> None:
            while not stop.wait(0.05):
                pub.publish(VehicleState())
                drone_side.session.put(f"{ns}-bad/state", b"")   # not a drone id: never reported
        th = threading.Thread(target=publish, daemon=True)
        th.start()
        try:
            assert discover_drones(ground, 1.0) == [f"{ns}d1"]
            gcs = Gcs(ground, GcsConfig(profile=stream_profile("resilient"), client_id="op", pattern="hover"))
            assert wait_for(lambda: f"{ns}d1" in gcs.drones, 5.0), list(gcs.drones)
            assert list(gcs.drones) == [f"{ns}d1"]
        finally:
            stop.set()
            th.join()


def test_a_mission_for_a_missing_drone_names_the_drones_that_are_there(ns: str) -> None:
    from gcs.dashboard import RateMeter, plain_lines
    from gcs.mission import Mission

    with spinning_nodes(ns) as (drone_side, ground):
        gcs = Gcs(ground, GcsConfig(drones=[f"{ns}d2"], profile=stream_profile("resilient"), client_id="op",
                                    pattern="hover"))
        lonely = Gcs(ground, GcsConfig(profile=stream_profile("resilient"), client_id="op2", pattern="hover"))
        assert "no drone heard yet" in plain_lines(lonely, RateMeter())[0]
        missing = Mission(gcs, gcs.drones[f"{ns}d2"], 1.0, lambda *_: None)
        assert "no drone seen on the network" in missing._not_heard()
        pub = drone_side.create_publisher(VehicleState, f"/{ns}d1/state", 10)
        stop = threading.Event()

        def publish() -> None:
            while not stop.wait(0.05):
                pub.publish(VehicleState())
        th = threading.Thread(target=publish, daemon=True)
        th.start()
        try:
            assert wait_for(lambda: f"{ns}d1" in gcs.seen(), 5.0)
            assert list(gcs.drones) == [f"{ns}d2"]          # asked for d2 only: d1 is seen, not flown
            assert missing._not_heard() == f"no state from {ns}d2; seen on the network: {ns}d1"
        finally:
            stop.set()
            th.join()
