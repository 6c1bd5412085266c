"""The drone's takeoff, goto and land as ROS 2 actions (companion/flight_actions.py), flown on the simulator:
feedback on the way, success where the goal asked, refusals (control, fence, not flying) as aborted goals
that name the reason, cancel holding where the drone is."""
from __future__ import annotations

import math

from cli_helpers import cli
from conftest import wait_for
from rigs import OP, Observer, drone, rig, spin

from drone_contract.actions import action_types
from zenoh_robot import Node, SessionConfig
from zenoh_robot.actions import GoalStatus

TYPES = action_types()


def _client(r, name: str, action):
    c = r.ground.create_action_client(action, f"/{r.companion.config.drone_id}/{name}")
    assert c.wait_for_server(10.0), f"no {name} action server"
    return c


def _send(client, goal, timeout: float = 60.0):
    feedback: list = []
    handle = client.send_goal_async(goal, feedback_callback=lambda m: feedback.append(m.feedback)).result(15.0)
    assert handle.accepted
    return handle, feedback, handle.get_result_async()


def test_takeoff_goto_land_fly_with_feedback(ns: str) -> None:
    with rig(ns) as r:
        takeoff, goto, land = (_client(r, "takeoff", TYPES.takeoff), _client(r, "goto", TYPES.goto),
                               _client(r, "land", TYPES.land))
        assert wait_for(lambda: r.sim.armable, 15)
        assert r.op.command("arm").success
        _, fb, res = _send(takeoff, TYPES.takeoff.Goal(client_id="op", altitude_m=4.0))
        out = res.result(60)
        assert out.status == GoalStatus.STATUS_SUCCEEDED, out.result.message
        assert out.result.success and out.result.altitude_m > 3.5 and abs(r.sim.altitude - 4.0) < 0.6
        assert fb and fb[0].remaining_m > fb[-1].remaining_m
        # goto: flown in Hold by PX4 (DO_REPOSITION), feedback counting down
        _, fb, res = _send(goto, TYPES.goto.Goal(client_id="op", north_m=10.0, east_m=-5.0, altitude_m=6.0))
        out = res.result(60)
        assert out.status == GoalStatus.STATUS_SUCCEEDED, out.result.message
        assert math.dist((out.result.north_m, out.result.east_m, out.result.altitude_m), (10, -5, 6)) <= 1.0
        assert r.sim.mode == "AUTO.LOITER"
        assert len(fb) >= 2 and fb[0].distance_m > fb[-1].distance_m
        # land: ends on the ground
        _, fb, res = _send(land, TYPES.land.Goal(client_id="op"))
        out = res.result(60)
        assert out.status == GoalStatus.STATUS_SUCCEEDED, out.result.message
        assert r.sim.landed and fb


def test_refusals_abort_the_goal_with_the_reason_and_cancel_holds(ns: str) -> None:
    with rig(ns, fence_radius_m=40.0) as r:
        takeoff, goto = _client(r, "takeoff", TYPES.takeoff), _client(r, "goto", TYPES.goto)
        # Not flying: a goto is refused before PX4 hears of it.
        _, _, res = _send(goto, TYPES.goto.Goal(client_id="op", north_m=5.0, east_m=0.0, altitude_m=5.0))
        out = res.result(30)
        assert out.status == GoalStatus.STATUS_ABORTED and "not flying" in out.result.message
        assert wait_for(lambda: r.sim.armable, 15)
        assert r.op.command("arm").success        # op holds control now
        # Another GCS: refused by the control gate, told who holds control; the drone stays on the ground.
        _, _, res = _send(takeoff, TYPES.takeoff.Goal(client_id="intruder", altitude_m=5.0))
        out = res.result(30)
        assert out.status == GoalStatus.STATUS_ABORTED and "op is in control" in out.result.message
        assert r.sim.altitude < 0.3
        _, _, res = _send(takeoff, TYPES.takeoff.Goal(client_id="op", altitude_m=3.0))
        assert res.result(60).status == GoalStatus.STATUS_SUCCEEDED
        # Outside the companion's 40 m fence: refused, naming the fence.
        _, _, res = _send(goto, TYPES.goto.Goal(client_id="op", north_m=60.0, east_m=0.0, altitude_m=5.0))
        out = res.result(30)
        assert out.status == GoalStatus.STATUS_ABORTED and "geofence" in out.result.message
        # Canceled on the way: the drone stops and holds short of the point.
        handle, fb, res = _send(goto, TYPES.goto.Goal(client_id="op", north_m=35.0, east_m=0.0, altitude_m=3.0))
        assert wait_for(lambda: r.sim.position[0] > 4.0, 30), r.sim.position
        handle.cancel_goal_async().result(15)
        out = res.result(30)
        assert out.status == GoalStatus.STATUS_CANCELED and "canceled" in out.result.message
        assert wait_for(lambda: math.hypot(*r.sim.velocity[:2]) < 0.3, 15)
        stopped = float(r.sim.position[0])
        assert stopped < 30.0
        assert not wait_for(lambda: r.sim.position[0] > stopped + 2.0, 2.0)


def test_cli_and_gcs_call_the_drone_actions_over_px4_zenoh(ns: str, own_domain: int) -> None:
    """The companion as a process on PX4's Zenoh module (the simulator): `zenoh-robot action send_goal` finds
    the drone's types through the entry point (no .action file), `gcs cmd DRONE goto N,E,ALT` prints the
    feedback and the result, a ROS 2 client's view of the graph lists the three servers."""
    with drone(ns, backend="zenoh") as (sim, proc), Node("observer", config=SessionConfig()) as node:
        spin(node)
        obs = Observer(node, ns)
        assert wait_for(lambda: obs.state is not None and obs.state.armable, 30), proc.poll()
        assert obs.command("arm").success
        out = cli("action", "send_goal", "-f", f"/{ns}/takeoff", "zenoh_robot_drone/action/Takeoff",
                  f"{{client_id: {OP}, altitude_m: 3.0}}", "--timeout", "15", timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "remaining_m" in out.stdout and "success: true" in out.stdout.lower(), out.stdout
        assert sim.altitude > 2.5
        out = cli("gcs", "cmd", ns, "goto", "6,3,4", "--gcs-id", OP, "--timeout", "15", timeout=120)
        assert out.returncode == 0, out.stdout + out.stderr
        assert f"{ns} goto: ok" in out.stdout and "m to go" in out.stdout, out.stdout
        assert math.dist(sim.position, (6.0, 3.0, -4.0)) < 1.2, sim.position
        listed = cli("action", "list", timeout=60)
        assert all(f"/{ns}/{a}" in listed.stdout for a in ("takeoff", "goto", "land")), listed.stdout
        bad = cli("gcs", "cmd", ns, "goto", "6,3", "--gcs-id", OP)
        assert bad.returncode == 2 and "NORTH,EAST,ALTITUDE" in bad.stderr and "Traceback" not in bad.stderr


def test_a_ros2_wire_client_finds_the_actions_beside_the_ros2_topics(ns: str, own_domain: int) -> None:
    """`companion --ros2-topics`: the drone's actions on ROS 2's wire too (rmw_zenoh's keys and tokens), so a
    ROS 2 action client calls /<drone>/takeoff; here refused for a client that does not hold control."""
    from zenoh_robot.wire import ros2_wire

    domain = 40 + own_domain % 100
    with drone(ns, 1, "--ros2-topics", "--ros-domain-id", str(domain)) as (sim, proc), \
            Node("ros2_client", config=SessionConfig(domain=0), wire=ros2_wire(domain)) as node:
        spin(node)
        client = node.create_action_client(TYPES.takeoff, f"/{ns}/takeoff")
        assert client.wait_for_server(30.0), proc.poll()
        res = client.send_goal(TYPES.takeoff.Goal(client_id="", altitude_m=3.0), timeout=30.0)
        assert res is not None and res.status == GoalStatus.STATUS_ABORTED
        assert "client_id" in res.result.message and sim.altitude < 0.3


def test_a_takeoff_goal_while_disarmed_aborts_at_once_naming_it(ns: str) -> None:
    with rig(ns) as r:
        takeoff = _client(r, "takeoff", TYPES.takeoff)
        _, _, res = _send(takeoff, TYPES.takeoff.Goal(client_id="op", altitude_m=3.0))
        out = res.result(30)
        assert out.status == GoalStatus.STATUS_ABORTED and "not armed" in out.result.message, out.result.message
        assert r.sim.altitude < 0.3


def test_without_the_ros2_extra_the_companion_flies_without_its_actions() -> None:
    """rosbags absent (the `drone` extra alone): the actions are off with one warning, never a failed start;
    `gcs cmd goto` says what is missing in one line."""
    import subprocess
    import sys

    script = ("import sys, logging; sys.modules['rosbags'] = None; logging.basicConfig()\n"
              "from companion.app import flight_actions\n"
              "from gcs.goto import send_goto\n"
              "print('actions:', flight_actions(None, None, None))\n"
              "print(send_goto(None, 'uav1', 'op', (1.0, 2.0, 3.0), 1.0))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "actions: None" in out.stdout and "need the ros2 extra" in out.stderr, (out.stdout, out.stderr)
    assert "(False, \"uav1 goto: FAILED the drone's action types need the ros2 extra" in out.stdout, out.stdout
