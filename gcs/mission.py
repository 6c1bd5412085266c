"""A scripted flight: wait for the drone, OFFBOARD, arm, fly the pattern, land.

Setpoints stream from the GCS's timer the whole time, starting at the drone's current
position (see gcs/planner.py), so PX4's rule that OFFBOARD needs a setpoint stream beforehand
is met and a mission may start anywhere. Commands go through the drone's command
service and are retried while the answer is a lost request or reply (a lossy link), never
when the drone refused: a refusal is the answer.

The mission tells the truth: it fails, says why and stops at once when the companion
reports a failsafe (deadline missed, PX4 left OFFBOARD, control lost) or refuses this
GCS's setpoints, or when the drone is not doing what the mission asked.

Several drones (``run_swarm_mission``): each flies its own mission on its own thread, at
the same time. A drone that fails is reported (and put on hold) and, by the policy, the
others ``continue`` their missions or ``hold`` where they are at once, each told why.

``Mission`` is one drone's flight: each step a method (``wait_connected``, ``start_offboard``,
``wait_armable``, ``arm``, ``climb``, ``fly_pattern``, ``land``), each run in ``fly``'s order;
a step the drone did not do is recorded and raises ``MissionFailed``.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from drone_contract.commands import NO_SETPOINTS_YET, POSITION_UNKNOWN
from drone_contract.messages import CommandResult

from .app import DroneView, Gcs

ON_FAILURE = ("continue", "hold")
# PX4 SITL passes its pre-arm checks ~4 s after boot; a real vehicle's GPS fix can take longer.
ARMABLE_TIMEOUT_S = 30.0
OFFBOARD_START_WAIT_S = 15.0   # asking again while the drone has none of our setpoints or no position yet


class MissionFailed(Exception):
    pass


class Mission:
    """One drone's scripted flight (see the module docstring); ``abort`` (set by a swarm's ``hold``
    policy) stops it as a failure, ``why()`` saying which drone's failure it was."""

    def __init__(self, gcs: Gcs, drone: DroneView, duration: float, log: Callable[..., None],
                 abort: threading.Event | None = None, why: Callable[[], str] | None = None,
                 out: dict[str, Any] | None = None) -> None:
        self.gcs, self.drone, self.duration, self.log = gcs, drone, duration, log
        self.abort = abort or threading.Event()
        self.why = why or (lambda: "aborted")
        self.out: dict[str, Any] = out if out is not None else {"ok": False, "steps": [], "result": ""}
        self._failures_at_start = len(drone.failures)
        self._landing = False   # a drone already landing lands: another drone's failure does not hold it in the air

    def run(self) -> dict[str, Any]:
        """The flight and its outcome: what the mission summary and the swarm's policy read."""
        out, drone = self.out, self.drone
        try:
            self.fly()
            out["ok"] = True
            out["result"] = (f"ok: flew the {drone.pattern_name} pattern for {self.duration:.0f} s, landed and "
                             f"disarmed (largest distance from the path {drone.plan.max_path_error:.2f} m, "
                             f"mean {drone.plan.mean_path_error:.2f} m)")
        except MissionFailed as exc:
            out["result"] = f"FAILED: {exc}"
            if drone.state is not None and drone.state.armed and drone.in_control:
                drone.freeze()
                res = drone.command("hold")   # whatever went wrong, do not leave it following a stale plan
                self.log(f"mission: hold after failure: {'ok' if res.success else 'FAILED'} {res.message}")
        # Against the drone's own path (its formation slot's), from when it joined it (gcs/planner.py).
        out["max_path_error_m"] = drone.plan.max_path_error
        out["mean_path_error_m"] = drone.plan.mean_path_error
        out["joined_path"] = drone.plan.on_path
        out["asked_s"] = self.duration
        out.setdefault("offboard_s", 0.0)
        out["offboard_share"] = out["offboard_s"] / self.duration if self.duration > 0 else float("nan")
        out["failures"] = list(drone.failures)
        self.log(f"mission: {drone.id}: {out['result']}")
        return out

    def fly(self) -> None:
        """Every step in order; MissionFailed at the first the drone did not do."""
        self.wait_connected()
        time.sleep(0.3)   # a few setpoints from the drone's position reach the companion first
        self.start_offboard()
        self.wait_armable()
        self.arm()
        self.climb()
        self.fly_pattern()
        self.land()

    # -- the steps -------------------------------------------------------------------
    def wait_connected(self) -> None:
        drone = self.drone
        connected = self._until(lambda: bool(drone.state and drone.state.connected and drone.setpoints_sent > 5),
                                30.0)
        # Setpoints go only to a drone nobody else controls (gcs/app.py): say so rather than time out mutely.
        self._step("drone connected", connected,
                   "" if connected else self._not_heard() if drone.state is None else
                   f"{drone.state.controller} is in control of {drone.id}: no setpoints sent (take over with "
                   "--take-control)" if not drone.may_stream else "")

    def _not_heard(self) -> str:
        others = [d for d in self.gcs.seen() if d != self.drone.id]
        return f"no state from {self.drone.id}; " + (f"seen on the network: {', '.join(others[:10])}" if others else
                                                     "no drone seen on the network (is its companion running, in "
                                                     "this domain, reachable with these Zenoh flags?)")

    def start_offboard(self) -> None:
        # Refused for want of our setpoints (a lossy link at start-up may carry none of the first ones) or
        # of PX4's local position (its estimator has none yet), asked again while that lasts; any other
        # refusal, or one that does not pass in time, fails.
        end = time.monotonic() + OFFBOARD_START_WAIT_S
        while True:
            res = self._send("offboard_start")
            no_setpoints = res.message.startswith(NO_SETPOINTS_YET)
            if res.success or not (no_setpoints or POSITION_UNKNOWN in res.message) or time.monotonic() >= end:
                self._step("offboard_start", res.success, res.message)
                return
            self.log(f"mission: {self.drone.id}: offboard_start refused ({res.message}); asking again while "
                     + ("the setpoints stream" if no_setpoints else "PX4 has no local position"))
            self._until(lambda: False, 1.0)

    def wait_armable(self) -> None:
        # Like an operator: arm once PX4's pre-arm checks pass (real PX4 refuses for ~4 s after boot,
        # "Preflight Fail: heading estimate not stable"), not at once and not after a fixed sleep.
        drone = self.drone
        armable = self._until(lambda: bool(drone.state and drone.state.armable), ARMABLE_TIMEOUT_S)
        self._step("armable", armable, "" if armable else
                   f"PX4's pre-arm checks did not pass within {ARMABLE_TIMEOUT_S:g} s (mode "
                   f"{drone.state.mode_label if drone.state else '?'}): see the drone's log for PX4's reason")

    def arm(self) -> None:
        self._command("arm")

    def climb(self) -> None:
        drone, alt = self.drone, self.gcs.config.altitude
        climbed = self._until(lambda: bool(drone.state and -drone.state.position[2] > 0.8 * alt), 30.0)
        self._step("climb", climbed, "" if climbed else
                   f"altitude {-drone.state.position[2] if drone.state else 0:.1f} m after 30 s (asked {alt:g} m)")

    def fly_pattern(self) -> None:
        drone, out, duration = self.drone, self.out, self.duration
        drone.plan.start_pattern()
        self.log(f"mission: {drone.id}: flying the {drone.pattern_name} pattern for {duration:.0f} s")
        start = time.monotonic()
        end = start + duration
        # The pattern's window (wall clock), for figures taken over the flight itself (drone_lab's swarm).
        out["pattern_window"] = [time.time(), float("nan")]
        while time.monotonic() < end:
            self._check()
            s = drone.state
            if s is not None and (not s.in_session_mode or s.offboard_state != "active"):
                self._step("offboard", False, f"drone left the offboard session: mode {s.mode_label}, "
                                              f"companion {s.offboard_state or '?'} {s.failsafe}".strip())
            out["offboard_s"] = min(time.monotonic() - start, duration)   # in OFFBOARD, as the drone last said
            out["pattern_window"][1] = time.time()
            time.sleep(0.2)
        s = drone.state
        if s is not None and s.in_session_mode and s.offboard_state == "active":
            out["offboard_s"] = duration

    def land(self) -> None:
        drone = self.drone
        drone.freeze()
        self._landing = True
        self._command("land")
        drone.plan.done = True   # PX4 lands by itself: the companion has ended the session and would ignore setpoints
        landed = self._until(lambda: bool(drone.state and drone.state.landed and not drone.state.armed), 40.0)
        self._step("landed and disarmed", landed)

    # -- what every step uses --------------------------------------------------------
    def _step(self, name: str, ok: bool, detail: str = "") -> None:
        self.out["steps"].append({"step": name, "ok": ok, "detail": detail, "t": time.time()})
        self.log(f"mission: {self.drone.id}: {name}: {'ok' if ok else 'FAILED'} {detail}")
        if not ok:
            raise MissionFailed(f"{name}: {detail}" if detail else name)

    def _check(self) -> None:
        if self.abort.is_set() and not self._landing:
            self._step("other drones fine", False, self.why())
        if len(self.drone.failures) > self._failures_at_start:
            self._step("no failsafe, no refused setpoint", False, self.drone.failures[-1])

    def _until(self, pred: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self._check()
            if pred():
                return True
            time.sleep(0.1)
        return pred()

    def _send(self, name: str, value: float = 0.0) -> CommandResult:
        # One call: the client retries it under one request id and the companion runs it once
        # (zenoh_robot/services/retry.py); a second call is a new command, made only after a refusal (start_offboard).
        t0 = time.monotonic()
        res = self.drone.command(name, value)
        self.out.setdefault("commands", []).append({"command": name, "ok": res.success,
                                                     "latency_s": time.monotonic() - t0, "detail": res.message})
        return res

    def _command(self, name: str, value: float = 0.0) -> None:
        res = self._send(name, value)
        self._step(name, res.success, res.message)


def run_mission(gcs: Gcs, drone_id: str, duration: float, log: Callable[..., None],
                abort: threading.Event | None = None, why: Callable[[], str] | None = None) -> dict[str, Any]:
    """One drone's mission (``Mission``), the drone taken on by the GCS if it was not yet."""
    drone = gcs.add_drone(drone_id)
    drone.plan.fly = False
    return Mission(gcs, drone, duration, log, abort, why).run()


def run_swarm_mission(gcs: Gcs, drone_ids: list[str], duration: float, log: Callable[..., None],
                      on_failure: str = "continue", abort: threading.Event | None = None) -> dict[str, Any]:
    """Every drone's mission at once; ``on_failure``: the others ``continue`` or ``hold``; ``abort`` (the
    operator's Ctrl-C) holds them all."""
    if on_failure not in ON_FAILURE:
        raise ValueError(f"on_failure must be one of {ON_FAILURE}, got {on_failure!r}")
    if len(set(drone_ids)) != len(drone_ids) or not drone_ids:
        raise ValueError(f"a swarm mission needs distinct drones, got {drone_ids}")
    abort = abort or threading.Event()
    first_failure: list[str] = []
    lock = threading.Lock()
    results: dict[str, dict[str, Any]] = {}

    def why() -> str:
        return f"held: {first_failure[0]} (--on-failure hold)" if first_failure else "held"

    def one(drone_id: str) -> None:
        res = run_mission(gcs, drone_id, duration, log, abort, why)
        with lock:
            results[drone_id] = res
            if not res["ok"] and not first_failure and not abort.is_set():
                first_failure.append(f"{drone_id} failed: {res['result']}")
                if on_failure == "hold":
                    log(f"mission: {drone_id} failed; holding every other drone")
                    abort.set()
                else:
                    log(f"mission: {drone_id} failed; the others go on (--on-failure continue)")

    threads = [threading.Thread(target=one, args=(d,), name=f"mission-{d}", daemon=True) for d in drone_ids]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    ok = [d for d in drone_ids if results.get(d, {}).get("ok")]
    failed = [d for d in drone_ids if d not in ok]
    result = (f"ok: all {len(ok)} drones flew, landed and disarmed" if not failed else
              f"FAILED: {len(failed)} of {len(drone_ids)} drones did not finish ({', '.join(failed)}); "
              f"{first_failure[0] if first_failure else ''}")
    log(f"mission: {result}")
    return {"ok": not failed, "result": result, "on_failure": on_failure, "drones": results,
            "failed": failed}


def _fly(gcs: Gcs, drone: DroneView, duration: float, out: dict[str, Any], log: Callable[..., None],
         abort: threading.Event, why: Callable[[], str]) -> None:
    """The steps alone, into ``out`` (tests/wing/test_mission_offboard_start.py flies a stand-in drone)."""
    Mission(gcs, drone, duration, log, abort, why, out).fly()
