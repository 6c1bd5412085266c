"""One drone id, one vehicle (issue #42): the GCS never merges two companions' states, says at once when
two claim one id, and shows a matched stream that sends nothing ("uav3 sensor: publisher seen, 0 samples
in 5 s"); the companion that started later stops."""
from __future__ import annotations

import functools
import threading
from typing import Any

from conftest import spinning_nodes, wait_for

from companion.app import Companion
from drone_contract.messages import VehicleState
from drone_contract.streams import stream_profile
from gcs.app import Gcs, GcsConfig
from gcs.dashboard import RateMeter, plain_lines
from gcs.summary import summarize
from gcs.vehicle_identity import SWITCH_AFTER_S, StateSource
from zenoh_robot.claim import Claim, claim_key, claim_scope
from zenoh_robot.events import DuplicateNodeInfo
from zenoh_robot.msgs import SensorCombined


def test_two_companions_states_are_never_merged_and_a_silent_sensor_shows(ns: str) -> None:
    drone = f"{ns}d1"
    with spinning_nodes(ns) as (drone_side, ground):
        first = drone_side.create_publisher(VehicleState, f"/{drone}/state", 10)
        second = drone_side.create_publisher(VehicleState, f"/{drone}/state", 10)
        drone_side.create_publisher(SensorCombined, f"/{drone}/sensor", 10)    # matched, never puts
        stop = threading.Event()
        go_second = threading.Event()

        def publish() -> None:
            while not stop.wait(0.05):
                first.publish(VehicleState(mode="AUTO.LOITER", connected=True, position=[1.0, 1.0, -1.0]))
                if go_second.is_set():
                    second.publish(VehicleState(mode="OFFBOARD", connected=True, position=[9.0, 9.0, -9.0]))
        th = threading.Thread(target=publish, daemon=True)
        th.start()
        try:
            gcs = Gcs(ground, GcsConfig(profile=stream_profile("resilient"), client_id="op", pattern="hover"))
            assert wait_for(lambda: drone in gcs.drones and gcs.drones[drone].state is not None, 5.0)
            view = gcs.drones[drone]
            go_second.set()
            assert wait_for(lambda: "duplicate_id" in view.alerts.now, 5.0)
            assert wait_for(lambda: view.source.ignored >= 5, 5.0)
            assert view.state is not None and view.state.mode == "AUTO.LOITER"     # only the first vehicle's
            assert "two companions publish this drone's state" in " ".join(plain_lines(gcs, RateMeter()))
            assert wait_for(lambda: "silent_sensor" in view.alerts.now, 15.0), view.alerts.now
            assert f"{drone} sensor: publisher seen, 0 samples in 5 s" in plain_lines(gcs, RateMeter())[0]
            s = summarize(gcs, "resilient")["drones"][drone]
            assert s["state_ignored"] >= 5 and any("silent_sensor" in a for a in s["alerts"])
        finally:
            stop.set()
            th.join()


def test_two_held_claims_on_one_id_are_raised_on_the_gcs_at_once(ns: str) -> None:
    drone = f"{ns}d2"
    with spinning_nodes(ns) as (drone_side, ground):
        gcs = Gcs(ground, GcsConfig(profile=stream_profile("resilient"), client_id="op", pattern="hover",
                                    drones=[drone]))
        view = gcs.drones[drone]
        scope = claim_scope(drone_side.wire.graph)
        one = drone_side.declare_liveliness_token(claim_key(scope, drone, "companion", Claim("aa11", 1, True)))
        assert not wait_for(lambda: "duplicate_claim" in view.alerts.now, 0.5)
        two = drone_side.declare_liveliness_token(claim_key(scope, drone, "companion", Claim("bb22", 2, True)))
        assert wait_for(lambda: "duplicate_claim" in view.alerts.now, 5.0)
        assert "2 companions claim this id (zids aa11, bb22)" in view.alerts.now["duplicate_claim"]
        two.undeclare()
        assert wait_for(lambda: "duplicate_claim" not in view.alerts.now, 5.0)
        one.undeclare()


def test_a_state_source_follows_a_restarted_companion_but_not_a_second_one() -> None:
    said: list[str] = []
    src = StateSource(said.append)
    assert src.accept(1, 10.0) and src.accept(1, 10.2)
    assert not src.accept(2, 10.3) and len(said) == 1 and src.duplicated(10.3)
    assert not src.accept(2, 10.4) and len(said) == 1        # said once per publisher
    assert src.accept(2, 10.2 + SWITCH_AFTER_S + 0.1)         # the first went quiet: a restart, followed
    assert src.publisher == 2 and src.ignored == 2


class _Reporter:
    def __init__(self) -> None:
        self.sent: list[tuple[str, str, str]] = []

    def event(self, kind: str, detail: str, action: str = "", *_: Any) -> None:
        self.sent.append((kind, detail, action))


def test_the_companion_that_started_later_stops_and_the_other_says_so() -> None:
    for yields in (True, False):
        c = Companion.__new__(Companion)
        c.events, c.yielded = _Reporter(), ""     # type: ignore[assignment]
        stopped: list[bool] = []
        c.on_yield = functools.partial(stopped.append, True)
        c._on_duplicate(DuplicateNodeInfo("/uav1/companion", "ff00", 1, yields))
        kind, detail, action = c.events.sent[0]   # type: ignore[attr-defined]
        assert kind == "duplicate_id" and "/uav1/companion is also running in session zid ff00" in detail
        assert (action, stopped, bool(c.yielded)) == (("stopping", [True], True) if yields
                                                      else ("keeps running", [], False))
