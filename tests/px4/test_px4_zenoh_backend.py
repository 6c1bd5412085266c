"""The companion on PX4's own Zenoh module (``--px4 zenoh:<endpoint>``), no MAVLink anywhere.

The test process runs the router PX4 would join and part D's ZenohSimulator (a Zenoh client of that
router, speaking PX4's protocol) so it can read the vehicle; the companion and the GCS are real child
processes. test_system.py flies its missions and deadline HOLDs over both backends; this adds what only
this backend has: PX4's topics never reach the GCS-facing session, parameters are refused by name.
"""
from __future__ import annotations

import threading

import pytest
from conftest import python_proc, stop_process, wait_for
from px4_helpers import wait_state_armable
from rigs import OP, Observer, drone, offboard_started

from zenoh_robot import Node

pytestmark = pytest.mark.usefixtures("own_domain")   # conftest's: a domain of its own


def test_px4s_topics_stay_on_the_px4_side_and_parameters_are_refused_by_name(ns: str) -> None:
    """arm, OFFBOARD, setpoints, land over PX4's Zenoh: no /fmu key on the GCS-facing session, set_param refused."""
    with drone(ns, backend="zenoh") as (sim, companion), Node("observer") as node:
        obs = Observer(node, ns)
        threading.Thread(target=node.spin, daemon=True).start()
        # PX4's topics stay on the PX4 side: the GCS-facing session sees none of them.
        leaked: list[str] = []
        spy = node.session.declare_subscriber("**", lambda s: leaked.append(str(s.key_expr))
                                              if "fmu/" in str(s.key_expr) else None)
        gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", ns, "--pattern", "hover",
                          "--altitude", "2.5")
        try:
            assert wait_for(lambda: obs.state is not None and obs.state.connected, 20), "no state from the drone"
            offboard_started(obs, gcs)
            wait_state_armable(obs)
            assert obs.command("arm").success
            assert wait_for(lambda: sim.mode == "OFFBOARD" and sim.altitude > 1.0, 20), (sim.mode, sim.altitude)
            assert sim.setpoints_received > 20
            refused = obs.command("set_param", 5.0, "MPC_XY_VEL_MAX")
            assert not refused.success and "not available over PX4's zenoh module" in refused.message
            assert obs.command("land").success
            assert wait_for(lambda: sim.landed and not sim.armed, 30), (sim.mode, sim.altitude)
        finally:
            stop_process(gcs)
            spy.undeclare()
        assert leaked == [], leaked[:3]
        out = stop_process(companion)
    summary_line = next((ln for ln in out.splitlines() if "zenoh client of" in ln), "")
    assert summary_line, out[-2000:]
