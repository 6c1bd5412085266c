"""A GCS that cannot keep up with a drone's sensor asks the drone for less (gcs/decimation.py, issue #42):
only the drone it controls, only for a real overload, never below the floor, out loud, undone on close."""
from __future__ import annotations

import math
import threading
import time

import pytest
from conftest import wait_for
from rigs import OP, drone, spin

from drone_contract.messages import VehicleState
from drone_contract.streams import stream_profile
from gcs.app import DroneView, Gcs, GcsConfig
from gcs.decimation import MIN_HZ, STEP_S, SensorDecimation
from gcs.shedding import Window
from gcs.summary import summarize
from zenoh_robot import Node

PROFILE = stream_profile("resilient")


def W(received: int, dropped: int, delivered: int, seconds: float = 5.0) -> Window:
    return Window(received, dropped, delivered, seconds)


@pytest.mark.fast
def test_two_windows_losing_a_fifth_ask_for_what_was_delivered() -> None:
    d = SensorDecimation("uav3")
    # 600 samples sent twice each (the resilient profile's copy): 1,200 arrivals, half dropped at the queue,
    # 300 samples delivered. One such window is not yet an overload (a loaded moment's stall); two in a row are.
    assert d.window(W(1200, 600, 300), asked_hz=200.0, in_control=True, now=95.0) is None
    step = d.window(W(1200, 600, 300), asked_hz=200.0, in_control=True, now=100.0)
    assert step is not None and step.kept_hz == 60.0 and step.rate_hz == 48.0    # 80 % of the 60/s delivered
    assert step.text == ("uav3 sensor: this GCS delivered 60 samples/s and its queue dropped 600 of 1,200 "
                         "arrivals in 5 s; asked the drone for 48 Hz (was 200) until this GCS closes")
    assert d.steps == 1 and d.last_hz == 48.0


@pytest.mark.fast
def test_rates_are_over_the_windows_own_length() -> None:
    """A starved executor runs the check late: 450 samples delivered over 7.5 s are 60/s, not 90."""
    d = SensorDecimation("uav3")
    assert d.window(W(1800, 900, 450, 7.5), 200.0, True, 0.0) is None
    step = d.window(W(1800, 900, 450, 7.5), 200.0, True, 7.5)
    assert step is not None and step.kept_hz == 60.0 and step.rate_hz == 48.0


@pytest.mark.fast
@pytest.mark.parametrize(("w", "asked", "in_control"), [
    (W(1200, 13, 590), 200.0, True),      # a hiccup (N=5 dropped 1-13 in 40 s): shed at the queue, named there
    (W(1200, 600, 300), 200.0, False),    # a monitoring GCS never changes a drone's downlink
    (W(0, 0, 0), 200.0, True),            # nothing arrived: the silent-stream alert's case, not this one
    (W(200, 180, 10), 10.0, True),        # at the floor already
    (W(1200, 300, 450), 50.0, True),      # delivered 90/s: 72 Hz would be above the drone's 50 already
    (W(1200, 600, 300), math.nan, True),  # the drone's rate unknown: nothing to compare with
    (W(1200, 600, 300, 0.0), 200.0, True),  # no time passed: no rate
])
def test_no_step_without_an_overload_this_gcs_may_act_on(w: Window, asked: float, in_control: bool) -> None:
    d = SensorDecimation("uav3")
    assert [d.window(w, asked, in_control, t) for t in (0.0, 5.0, 10.0)] == [None] * 3


@pytest.mark.fast
def test_a_quiet_window_between_resets_the_count() -> None:
    d = SensorDecimation("uav3")
    assert d.window(W(1200, 600, 300), 200.0, True, 0.0) is None
    assert d.window(W(1200, 0, 600), 200.0, True, 5.0) is None
    assert d.window(W(1200, 600, 300), 200.0, True, 10.0) is None and d.steps == 0


@pytest.mark.fast
def test_steps_are_spaced_and_floored() -> None:
    d = SensorDecimation("uav3")
    assert d.window(W(1200, 600, 300), 200.0, True, -5.0) is None
    assert d.window(W(1200, 600, 300), 200.0, True, 0.0) is not None
    assert d.window(W(480, 400, 40), 48.0, True, STEP_S - 0.1) is None      # the last step must take effect first
    step = d.window(W(480, 460, 10), 48.0, True, STEP_S)                    # delivered 2/s: the floor
    assert step is not None and step.rate_hz == MIN_HZ and d.steps == 2

def test_a_gcs_that_cannot_keep_up_asks_its_drone_for_less_and_puts_it_back(
        ns: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A real companion (200 Hz asked of its simulator, ~120 Hz given) and a GCS whose sensor callback takes
    20 ms: the GCS, in control, asks the drone for less, says so, and puts the drone's rate back on release."""
    monkeypatch.setattr("gcs.shedding.PERIOD_S", 1.0)
    monkeypatch.setattr("gcs.app.SHEDDING_PERIOD_S", 1.0)
    slow = threading.Event()
    handle = DroneView._on_sensor

    def slow_sensor(self: DroneView, msg: object, info: object) -> None:   # a GCS that cannot keep up
        if slow.is_set():
            time.sleep(0.02)
        handle(self, msg, info)   # type: ignore[arg-type]
    monkeypatch.setattr(DroneView, "_on_sensor", slow_sensor)   # before the subscription takes it

    def rate(view: DroneView | None = None, obs: list[VehicleState] | None = None) -> float:
        s = view.state if view is not None else (obs[-1] if obs else None)
        return float(s.sensor_rate_requested_hz) if s is not None else math.nan

    with drone(ns, 1, "--sensor-rate", "200") as (_sim, _proc):
        with Node("gcs") as node:
            gcs = Gcs(node, GcsConfig(drones=[ns], profile=PROFILE, client_id=OP, pattern="hover", auto_fly=False))
            spin(node)
            view = gcs.drones[ns]
            assert wait_for(lambda: view.state is not None and view.state.connected, 30), view.state
            assert rate(view) == 200.0
            assert view.command("take_control").success
            slow.set()
            assert wait_for(lambda: "decimated_sensor" in view.alerts.now, 30), (view.alerts.now, view.alerts.log)
            text = next(a for a in view.alerts.log if a.startswith("decimated_sensor"))    # the first step
            asked = float(text.split("asked the drone for ")[1].split(" Hz")[0])
            assert MIN_HZ <= asked < 0.9 * 200.0 and "(was 200)" in text, text
            # The drone took it (a loaded machine may have stepped down once more since: 10 s apart).
            assert wait_for(lambda: rate(view) == view.decimation.last_hz <= asked, 15), rate(view)
            s = summarize(gcs, "resilient")["drones"][ns]
            assert s["sensor_decimated"]["rate_hz"] <= asked and s["shed_by_gcs"]["sensor"] > 0
            slow.clear()
            gcs.release_control()                   # as the CLI does on exit: the rate goes back first
        with Node("observer") as observer:          # what any node now sees of the drone
            states: list[VehicleState] = []
            observer.create_subscription(VehicleState, f"/{ns}/state", lambda m: states.append(m), PROFILE.qos["state"])
            spin(observer)
            assert wait_for(lambda: rate(obs=states) == 200.0, 15), rate(obs=states)
