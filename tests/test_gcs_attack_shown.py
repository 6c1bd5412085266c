"""A drone under attack shows at the GCS (issue #37): the companion's state carries the running total
of sealed samples and calls it refused (forged, replayed, recorded before a restart); while it rises,
the dashboard's link column and the plain status line say so."""
from __future__ import annotations

import threading

from conftest import spinning_nodes, wait_for
from rich.console import Console

from drone_contract.messages import VehicleState
from drone_contract.streams import stream_profile
from gcs.app import Gcs, GcsConfig
from gcs.dashboard import RateMeter, plain_lines, render


def test_a_rising_refusal_count_marks_the_drone_under_attack(ns: str) -> None:
    with spinning_nodes(ns) as (drone_side, ground):
        pub = drone_side.create_publisher(VehicleState, f"/{ns}d1/state", 10)
        refused = [0]
        stop = threading.Event()

        def publish() -> None:
            while not stop.wait(0.05):
                pub.publish(VehicleState(mode="AUTO.LOITER", connected=True, link_refused=refused[0]))
        th = threading.Thread(target=publish, daemon=True)
        th.start()
        try:
            gcs = Gcs(ground, GcsConfig(profile=stream_profile("resilient"), client_id="op", pattern="hover"))
            assert wait_for(lambda: f"{ns}d1" in gcs.drones and gcs.drones[f"{ns}d1"].state is not None, 5.0)
            view, rates = gcs.drones[f"{ns}d1"], RateMeter()
            assert not view.under_attack and "ATTACK" not in " ".join(plain_lines(gcs, rates))
            refused[0] = 90
            assert wait_for(lambda: view.under_attack, 5.0)
            assert "UNDER ATTACK: 90 sealed samples refused" in " ".join(plain_lines(gcs, rates))
            console = Console(width=250, record=True)
            console.print(render(gcs, rates))
            assert "ATTACK (90 refused)" in console.export_text()
        finally:
            stop.set()
            th.join()
