"""What the GCS itself sheds, named (issue #42): a drone's sensor stream that this GCS's own queue drops
(its executor behind) raises ``shedding_sensor`` once, shows in the summary as the GCS's load, not the
link's loss, and clears once a window drops nothing."""
from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import pytest
from conftest import spinning_nodes, wait_for

from drone_contract.streams import stream_profile
from gcs.alerts import Alerts
from gcs.app import DroneView, Gcs, GcsConfig
from gcs.shedding import SheddingWatch
from gcs.summary import summarize
from zenoh_robot.msgs import SensorCombined


@pytest.mark.fast
def test_a_window_with_drops_raises_once_and_a_quiet_one_clears() -> None:
    alerts = Alerts("uav3")
    counters = SimpleNamespace(received=0, dropped=0)
    watch = SheddingWatch(alerts)
    watch.watch("sensor", SimpleNamespace(counters=counters))
    watch.watch("state", SimpleNamespace(counters=SimpleNamespace(received=0, dropped=50)))   # depth 1: by design
    counters.received, counters.dropped = 1000, 812
    watch.check()
    assert alerts.now == {"shedding_sensor": "uav3 sensor: this GCS drops samples (812 of 1,000 in 5 s): its "
                                             "queue is full, it cannot keep up; the newest are kept"}
    counters.received, counters.dropped = 2000, 1500
    watch.check()
    assert len(alerts.log) == 1                    # one episode, one alert (and one warning)
    counters.received = 3000
    watch.check()
    assert alerts.now == {} and watch.dropped == {"sensor": 1500} and watch.windows_shedding == {"sensor": 2}


def test_a_gcs_whose_sensor_queue_overflows_says_so(ns: str, monkeypatch: pytest.MonkeyPatch) -> None:
    drone = f"{ns}d1"
    monkeypatch.setattr("gcs.shedding.PERIOD_S", 0.5)
    monkeypatch.setattr("gcs.app.SHEDDING_PERIOD_S", 0.5)
    with spinning_nodes(ns) as (drone_side, ground):
        sensor = drone_side.create_publisher(SensorCombined, f"/{drone}/sensor", 10)
        slow = threading.Event()
        handle = DroneView._on_sensor

        def slow_sensor(self: DroneView, msg: SensorCombined, info: object) -> None:   # a GCS that cannot keep up
            if slow.is_set():
                time.sleep(0.01)
            handle(self, msg, info)
        monkeypatch.setattr(DroneView, "_on_sensor", slow_sensor)   # before the subscription takes it
        gcs = Gcs(ground, GcsConfig(drones=[drone], profile=stream_profile("resilient"), client_id="op",
                                    pattern="hover"))
        view = gcs.drones[drone]
        stop = threading.Event()

        def flood() -> None:
            while not stop.is_set():
                sensor.publish(SensorCombined())
                time.sleep(0.002)    # 500 Hz against a 10 ms callback: the depth-5 queue must drop
        th = threading.Thread(target=flood, daemon=True)
        th.start()
        try:
            slow.set()
            assert wait_for(lambda: "shedding_sensor" in view.alerts.now, 15.0), view.alerts.now
            s = summarize(gcs, "resilient")["drones"][drone]
            assert s["shed_by_gcs"]["sensor"] > 0 and any("shedding_sensor" in a for a in s["alerts"])
            stop.set()
            th.join()
            slow.clear()
            assert wait_for(lambda: "shedding_sensor" not in view.alerts.now, 15.0), view.alerts.now
        finally:
            stop.set()
