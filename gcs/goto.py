"""``gcs cmd DRONE goto N,E,ALT``: the drone's goto action (drone_contract.actions) with its progress.

The goal carries this GCS's id, so the companion's control gate judges it as any command; the lines
printed are the goal's feedback (at most one a second per drone) and its result, which names why when
the drone refused or stopped (not flying, outside the geofence, another GCS in control, canceled).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from drone_contract.actions import ACTION_NAMES, GOTO, action_types
from zenoh_robot import Node
from zenoh_robot.actions import GoalStatus

FEEDBACK_EVERY_S = 1.0
RESULT_TIMEOUT_S = 600.0   # a goal ends by itself (the companion gives up on no progress); this is a backstop


def parse_target(text: str | None) -> tuple[float, float, float]:
    """``N,E,ALT`` (metres north and east of the origin, altitude above home) -> floats; ValueError names it."""
    parts = (text or "").split(",")
    try:
        north, east, alt = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"goto needs NORTH,EAST,ALTITUDE in metres, e.g. 10,-5,8; got {text!r}") from None
    if not all(math.isfinite(v) for v in (north, east, alt)):
        raise ValueError(f"goto: {text!r} is not a finite point")
    return north, east, alt


def send_goto(node: Node, drone: str, client_id: str, target: tuple[float, float, float], timeout: float,
              say: Callable[[str], None] = print) -> tuple[bool, str]:
    """Fly ``drone`` to ``target``; (succeeded, the result line)."""
    try:
        goto = action_types().goto
    except ImportError as exc:
        return False, f"{drone} goto: FAILED the drone's action types need the ros2 extra ({exc})"
    client = node.create_action_client(goto, f"/{drone}/{ACTION_NAMES[GOTO]}", goal_timeout=timeout)
    try:
        if not client.wait_for_server(timeout):
            return False, f"{drone} goto: FAILED no goto action server within {timeout:g} s (companion too old, " \
                          "or without the ros2 extra)"
        last = [0.0]

        def feedback(msg: Any) -> None:
            now = time.monotonic()
            if now - last[0] >= FEEDBACK_EVERY_S:
                last[0] = now
                eta = msg.feedback.eta_s
                say(f"{drone} goto: {msg.feedback.distance_m:.1f} m to go"
                    + (f", ~{eta:.0f} s" if math.isfinite(eta) else ""))
        north, east, alt = target
        handle = client.send_goal_async(goto.Goal(client_id=client_id, north_m=north, east_m=east, altitude_m=alt),
                                        feedback_callback=feedback).result(timeout + 5.0)
        if not handle.accepted:
            return False, f"{drone} goto: FAILED goal rejected"
        res = handle.get_result_async().result(RESULT_TIMEOUT_S)
        ok = res.status == GoalStatus.STATUS_SUCCEEDED
        r = res.result
        return ok, (f"{drone} goto: {'ok' if ok else 'FAILED'} {r.message} "
                    f"(at N {r.north_m:.1f} E {r.east_m:.1f}, {r.altitude_m:.1f} m)")
    finally:
        client.destroy()
