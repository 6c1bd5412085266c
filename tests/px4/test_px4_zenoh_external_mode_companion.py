"""``zenoh-robot companion --px4 zenoh:<endpoint> --px4-mode NAME`` against the Zenoh simulator: the companion
registers NAME with PX4, answers PX4's arming check from its own state (no GCS in control -> "no", with the
reason), the GCS's offboard_start selects the mode instead of OFFBOARD, the GCS's setpoints fly through it,
and PX4 falls back to RTL when the companion process dies. The companion and the GCS are real processes;
bands are generous (loaded machines)."""
from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path

import pytest
from conftest import python_proc, stop_process, wait_for
from px4_helpers import wait_state_armable
from rigs import OP, Observer, drone, gcs_proc, offboard_started

from zenoh_robot import Node

pytestmark = pytest.mark.usefixtures("own_domain")   # conftest's: a domain of its own
EXT1, RTL = 23, 5


def test_companion_flies_as_a_px4_external_mode(ns: str) -> None:
    with drone(ns, 1, "--px4-mode", "zr companion", backend="zenoh") as (sim, companion), \
            Node("observer") as node:
        obs = Observer(node, ns)
        threading.Thread(target=node.spin, daemon=True).start()
        assert wait_for(lambda: obs.state is not None and obs.state.connected, 20), "no state from the drone"
        assert wait_for(lambda: [m.name for m in sim.mode_management.modes.values()] == ["zr companion"], 15), \
            "the companion did not register its mode"
        # nobody holds control yet: PX4 is told the mode cannot run, and why
        assert wait_for(lambda: sim.mode_management.report.cannot_arm.get(EXT1)
                        == "no GCS holds control; no offboard session", 5), sim.mode_management.report.cannot_arm
        gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", ns, "--pattern", "hover",
                          "--altitude", "2.5")
        try:
            offboard_started(obs, gcs)
            assert wait_for(lambda: sim.mode == "EXTERNAL1", 5), sim.mode      # the mode, not OFFBOARD
            assert wait_for(lambda: EXT1 not in sim.mode_management.report.cannot_arm, 5), \
                sim.mode_management.report.cannot_arm
            wait_state_armable(obs)
            assert obs.command("arm").success
            assert wait_for(lambda: sim.altitude > 1.0, 20), (sim.mode, sim.altitude)
            assert sim.mode == "EXTERNAL1" and obs.state is not None and obs.state.mode == "EXTERNAL1"
            # the GCS sees which way the drone is flown: the mode by its registered name, the session in it
            st = obs.state
            assert (st.mode_name, st.session_mode, st.in_session_mode) == ("zr companion", "EXTERNAL1", True), st
            assert st.mode_label == "zr companion (EXTERNAL1)"
            assert sim.commander.setpoints_outside_mode == 0, "a setpoint reached PX4 outside the mode"
            assert all(n == 0 for n in sim.misrouted.values())
            assert sim.check_replies and sim.check_replies[-1][3]
            companion.send_signal(signal.SIGKILL)       # the companion dies in flight
            t_kill = time.monotonic()
            assert wait_for(lambda: sim.mode == "AUTO.RTL", 5, interval=0.01), sim.mode
            fallback = time.monotonic() - t_kill
            print(f"\ncompanion killed in the mode -> PX4 in RTL {fallback:.3f} s")
            assert sim.armed and sim.failsafe_log[-1].cause == "external mode"
        finally:
            stop_process(gcs)


def test_gcs_loss_holds_first_and_the_check_says_why(ns: str) -> None:
    with drone(ns, 1, "--px4-mode", "zr companion", backend="zenoh") as (sim, _), Node("observer") as node:
        obs = Observer(node, ns)
        threading.Thread(target=node.spin, daemon=True).start()
        assert wait_for(lambda: obs.state is not None and obs.state.connected, 20), "no state from the drone"
        assert wait_for(lambda: bool(sim.mode_management.modes), 15), "the companion did not register its mode"
        gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", ns, "--pattern", "hover",
                          "--altitude", "2.5")
        try:
            offboard_started(obs, gcs)
            wait_state_armable(obs)
            assert obs.command("arm").success
            assert wait_for(lambda: sim.altitude > 1.0 and sim.mode == "EXTERNAL1", 20), (sim.mode, sim.altitude)
            gcs.send_signal(signal.SIGKILL)             # the GCS (and its setpoints) gone
            # the companion's own deadline failsafe acts first (Hold), before any PX4 fallback
            assert wait_for(lambda: sim.mode == "AUTO.LOITER", 10), sim.mode
            assert not any(e.cause == "external mode" for e in sim.failsafe_log)
            assert wait_for(lambda: "setpoints stale" in sim.mode_management.report.cannot_run.get(EXT1, ""), 5), \
                sim.mode_management.report.cannot_run
        finally:
            stop_process(gcs)


def test_the_gcs_mission_flies_through_the_mode_as_through_offboard(ns: str, tmp_path: Path) -> None:
    """The GCS's own mission (arm, climb, pattern, land) with a companion flying as an external mode: the GCS
    judges the session by the mode the companion says it flies in, never by OFFBOARD."""
    record = tmp_path / "gcs.json"
    with drone(ns, 1, "--px4-mode", "zr companion", backend="zenoh") as (sim, _):
        gcs = gcs_proc("--drones", ns, "--mission", "--duration", "3", "--pattern", "square", "--size", "3",
                       "--altitude", "2.5", "--record", str(record))
        out, _ = gcs.communicate(timeout=120)
        assert gcs.returncode == 0, out
        modes = [m.new for m in sim.mode_log]
        assert sim.commander.setpoints_outside_mode == 0, "a setpoint reached PX4 outside the mode"
    summary = json.loads(record.read_text())
    assert summary["mission"]["ok"], summary["mission"]
    assert "EXTERNAL1" in modes and "OFFBOARD" not in modes, modes
    assert modes[-1] in ("AUTO.LAND", "AUTO.LOITER"), modes
    d = summary["drones"][ns]
    assert d["final_state"]["landed"] and not d["final_state"]["armed"]
    assert d["max_path_error_m"] < 3.0, d["max_path_error_m"]
