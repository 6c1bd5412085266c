"""The GCS dashboard as an operator reads it: it fits the terminal it is in (80, 120, 200 columns: the
columns that matter for flying first, issue #39), the mission's steps and the latest events under it,
and a drone under attack shows (issue #37): the companion's state carries the running total of sealed
samples and calls it refused (forged, replayed, recorded before a restart); while it rises, the link
column and the plain status line say so."""
from __future__ import annotations

import threading

from conftest import spinning_nodes, wait_for
from rich.console import Console

from drone_contract.messages import VehicleState
from drone_contract.streams import stream_profile
from gcs.app import Gcs, GcsConfig
from gcs.dashboard import RateMeter, fit_columns, plain_lines, render


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


def test_the_table_fits_the_terminal_with_the_flying_columns_first(ns: str) -> None:
    with spinning_nodes(ns) as (drone_side, ground):
        pub = drone_side.create_publisher(VehicleState, f"/{ns}d1/state", 10)
        stop = threading.Event()

        def publish() -> None:
            while not stop.wait(0.05):
                pub.publish(VehicleState(mode="OFFBOARD", armed=True, landed=False, connected=True,
                                         position=[9.7, 3.3, -5.0], battery_remaining=0.87,
                                         offboard_state="active", controller="op", failsafe=""))
        th = threading.Thread(target=publish, daemon=True)
        th.start()
        try:
            gcs = Gcs(ground, GcsConfig(profile=stream_profile("resilient"), client_id="op", pattern="hover"))
            assert wait_for(lambda: f"{ns}d1" in gcs.drones and gcs.drones[f"{ns}d1"].state is not None, 5.0)
            rates = RateMeter()
            progress = ["12:00:01 mission: d1: climb: ok", "12:00:02 mission: d1: flying the hover pattern for 30 s"]
            for width in (80, 120, 200):
                console = Console(width=width, record=True)
                console.print(render(gcs, rates, width=width, progress=progress))
                text = console.export_text()
                assert max(len(line) for line in text.splitlines()) <= width, (width, text)
                for column in ("drone", "mode", "arm", "alt m", "link", "sp Hz", "batt"):
                    assert column in text, (width, column, text)
                assert "OFFBOARD" in text and "5.0" in text and "87%" in text, text
                assert ("this GCS" in text) or width < 120, text
                assert "flying the hover pattern" in text
                assert ("position (NED m)" in text) is (width >= 200)
        finally:
            stop.set()
            th.join()


def test_columns_are_chosen_by_need_and_shown_in_their_order() -> None:
    row = {"drone": "uav1", "mode": "OFFBOARD", "arm": "yes", "alt m": "5.0", "batt": "90%", "link": "ok",
           "sp Hz": "10.0", "offboard": "active", "control": "this GCS", "position (NED m)": "1.0, 2.0, -5.0"}
    assert fit_columns([row], 80) == ["drone", "mode", "arm", "alt m", "batt", "link", "offboard", "control", "sp Hz"]
    assert fit_columns([row], 20)[:3] == ["drone", "mode", "arm"]       # never dropped: cut to fit instead
    wide = fit_columns([row], 300)
    assert wide.index("position (NED m)") < wide.index("link") and wide[-1] == "failsafe"
