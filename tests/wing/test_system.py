"""The whole system over localhost: simulator, companion and GCS as they run on a drone.

The simulator runs in the test process (so the test can read its mode and the
setpoints that reached it), but talks to the companion only through real MAVLink over
UDP; the companion and the GCS are real child processes talking over Zenoh.
"""
from __future__ import annotations

import json
import math
import signal
import threading
import time
from pathlib import Path

import pytest
from conftest import stop_process, wait_for
from px4_helpers import assert_no_px4_failsafe, switched_at, wait_state_armable
from rigs import BACKENDS, OP, SETPOINT_QOS, Observer, drone, gcs_proc, offboard_started, spin

from drone_contract.messages import DroneSetpoint
from zenoh_robot import Node
from zenoh_robot.msgs import Header

# This module's processes (nodes `companion`, `gcs`) in a domain of their own (conftest's own_domain).
pytestmark = pytest.mark.usefixtures("own_domain")


@BACKENDS
def test_mission_end_to_end(ns: str, tmp_path: Path, backend: str) -> None:
    record, companion_record = tmp_path / "gcs.json", tmp_path / "companion.json"
    with drone(ns, 1, "--record", str(companion_record), "--sensor-rate", "200", backend=backend) as (sim, companion):
        gcs = gcs_proc("--drones", ns, "--mission", "--duration", "4", "--pattern", "square", "--size", "4",
                       "--altitude", "2.5", "--record", str(record))
        out, _ = gcs.communicate(timeout=120)
        assert gcs.returncode == 0, out
        modes = [m.new for m in sim.mode_log]
    summary = json.loads(record.read_text())
    d = summary["drones"][ns]
    assert summary["mission"]["ok"], summary["mission"]
    assert "OFFBOARD" in modes and modes[-1] in ("AUTO.LAND", "AUTO.LOITER")
    streams = d["streams"]
    assert streams["sensor"]["received"] > 200 and streams["sensor"]["rate_hz"] > 20
    assert streams["sensor"]["age_avg_ms"] < 100
    assert streams["state"]["received"] > 20
    # The camera gives way under load by design (companion/priority.py): frames flow and arrive within a second,
    # however loaded the machine; their freshness on a quiet one is the benchmarks' (docs/benchmarks.md).
    assert d["frames"] > 30 and streams["image"]["age_avg_ms"] < 1000
    assert d["max_path_error_m"] < 3.0
    assert d["final_state"]["landed"] and not d["final_state"]["armed"]
    # PX4 returns to OFFBOARD once disarmed after landing: the companion parks it, and its summary at
    # exit says what PX4 then was in (the demo printed "final mode OFFBOARD" before the heartbeat came).
    assert sim.mode != "OFFBOARD"
    assert json.loads(companion_record.read_text())["final_mode"] == sim.mode, sim.mode


@BACKENDS
def test_gcs_killed_companion_holds_then_resumes(ns: str, backend: str) -> None:
    with drone(ns, backend=backend) as (sim, companion), Node("observer") as node:
        obs = Observer(node, ns)
        spin(node)
        gcs = gcs_proc("--drones", ns, "--pattern", "hover", "--altitude", "2.5")
        try:
            assert wait_for(lambda: obs.state is not None and obs.state.connected, 20), "no state from the drone"
            offboard_started(obs, gcs)
            wait_state_armable(obs)
            assert obs.command("arm").success
            assert wait_for(lambda: sim.mode == "OFFBOARD" and sim.altitude > 1.0, 20)
            # Stamped before the signal: the companion's HOLD can come before wait() returns on a loaded machine.
            killed = time.monotonic()
            gcs.send_signal(signal.SIGKILL)
            gcs.wait()
            assert wait_for(lambda: sim.mode == "AUTO.LOITER", 10), f"mode {sim.mode}"
            held_after = switched_at(sim, "AUTO.LOITER", killed) - killed   # on the simulator's clock
            assert held_after < 1.0 + 2.5, f"HOLD only after {held_after:.1f} s"
            # Our HOLD came first: PX4's own offboard-loss failsafe (whichever mode) never fired.
            assert_no_px4_failsafe(sim)
            assert wait_for(lambda: any(e.kind == "setpoint_deadline_missed" for e in obs.events), 5)
            assert sim.armed and not sim.landed

            gcs = gcs_proc("--drones", ns, "--pattern", "hover", "--altitude", "2.5")
            time.sleep(1.0)
            assert sim.mode == "AUTO.LOITER", "resumed without being asked"
            offboard_started(obs, gcs)
            assert wait_for(lambda: sim.mode == "OFFBOARD", 5)
        finally:
            stop_process(gcs, 10.0)


def test_nan_setpoint_from_a_rogue_publisher_never_reaches_px4(ns: str) -> None:
    with drone(ns) as (sim, companion), Node("rogue") as node:
        obs = Observer(node, ns)
        spin(node)
        pub = node.create_publisher(DroneSetpoint, f"/{ns}/setpoint", SETPOINT_QOS)
        assert wait_for(lambda: obs.state is not None and obs.state.connected, 20)
        for i in range(5):
            pub.publish(DroneSetpoint(Header.now(seq=i), OP, 1.0, 2.0, -3.0))
            time.sleep(0.05)
        time.sleep(0.3)
        assert sim.setpoints_received == 0, "a setpoint outside an offboard session reached PX4"
        stream = threading.Event()

        def keep_streaming() -> None:
            while not stream.is_set():
                pub.publish(DroneSetpoint(Header.now(), OP, 1.0, 2.0, -3.0))
                time.sleep(0.1)
        threading.Thread(target=keep_streaming, daemon=True).start()
        try:
            assert wait_for(lambda: obs.command("offboard_start").success, 10, interval=0.5)
            assert wait_for(lambda: sim.last_setpoint is not None and sim.last_setpoint.position == (1.0, 2.0, -3.0), 5)
        finally:
            stream.set()
        for i in range(5, 15):
            pub.publish(DroneSetpoint(Header.now(seq=i), OP, math.nan, 2.0, -3.0))
            time.sleep(0.05)
            assert all(math.isfinite(v) for v in sim.last_setpoint.position)
        assert wait_for(lambda: obs.state is not None and obs.state.setpoints_rejected >= 10, 5)
        assert wait_for(lambda: any(e.kind == "setpoint_rejected" and "non-finite" in e.detail for e in obs.events), 5)
        assert sim.last_setpoint.position == (1.0, 2.0, -3.0)
        # Bad commands get an error reply, never silence, and change nothing.
        res = obs.command("dance")
        assert not res.success and "unknown command 'dance'" in res.message
        res = obs.command("takeoff", 500.0)
        assert not res.success and "outside" in res.message
        assert not sim.armed
        assert obs.command("offboard_stop").success


def test_two_drones_each_get_only_their_setpoints(ns: str) -> None:
    a, b = f"{ns}a", f"{ns}b"
    with drone(a, 1) as (sim_a, _), drone(b, 2) as (sim_b, _), Node("gcs2") as node:
        spin(node)
        pubs = {d: node.create_publisher(DroneSetpoint, f"/{d}/setpoint", SETPOINT_QOS) for d in (a, b)}
        observers = {d: Observer(node, d) for d in (a, b)}
        xs = {a: 1.5, b: -1.5}
        seen: dict[str, set] = {a: set(), b: set()}
        started: set[str] = set()
        replies: dict[str, str] = {}
        # How long this may take is not what is asserted (each drone's own setpoints, never the other's): on
        # four loaded workers one drone's first setpoint had not arrived after 30 s (a CI rehearsal).
        # The setpoints stream on a thread of their own, as a GCS's timer sends them: a blocking offboard_start
        # on the test's thread must not starve the other drone's stream (its deadline failsafe then froze the
        # target at the vehicle's position, 0.0, and held: seen in rehearsals, not the cross-talk asserted).
        stop = threading.Event()

        def stream() -> None:
            while not stop.wait(0.05):
                for d, pub in pubs.items():
                    pub.publish(DroneSetpoint(Header.now(), OP, xs[d], 0.0, -2.0))
        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        deadline = time.monotonic() + 60
        try:
            while time.monotonic() < deadline and not all(len(s) and xs[d] in s for d, s in seen.items()):
                for d, sim in ((a, sim_a), (b, sim_b)):
                    obs = observers[d]
                    # A session each (offboard_start): only then do setpoints reach PX4.
                    if d not in started and obs.state is not None and obs.state.connected:
                        res = obs.command("offboard_start")
                        replies[d] = res.message
                        if res.success:
                            started.add(d)
                    if sim.last_setpoint is not None:
                        seen[d].add(sim.last_setpoint.position[0])
                time.sleep(0.1)
        finally:        # the stream never outlives the node it publishes on
            stop.set()
            streamer.join(2.0)
        # When it fails, say where the chain stopped: no state heard, offboard_start refused, or no setpoint.
        why = {d: {"state heard": observers[d].state is not None, "offboard_start": replies.get(d),
                   "setpoints received by the sim": sim.setpoints_received}
               for d, sim in ((a, sim_a), (b, sim_b))}
        assert seen[a] == {1.5} and seen[b] == {-1.5}, (seen, why)
