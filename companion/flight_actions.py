"""The drone's long commands as ROS 2 actions: ``takeoff``, ``goto`` and ``land`` (drone_contract.actions).

Each goal is a command of the command service with a progress report: it passes the same gates
(CommandDesk: control, policy, the PX4 worker's lane), then its execution thread watches the vehicle
and publishes feedback until the drone is where the goal asked, or aborts naming why (the command was
refused, the mode changed under it, the drone disarmed, it took too long). Nothing is retried: a goal
whose command failed tells its sender and ends.

- takeoff: ``takeoff`` command; succeeds once PX4 has left AUTO.TAKEOFF near the altitude asked.
- goto: DO_REPOSITION (Hold flies to the point at MPC_XY_CRUISE); the drone must be flying, the point
  inside the companion's geofence; succeeds within ``GOTO_REACHED_M`` of it.
- land: ``land`` command; succeeds on the ground.
- cancel (any of them): the drone holds where it is (``hold``, or for a goto a reposition to here),
  sent as the goal's sender: holding is the safe side whoever asks, and a canceled goal never ends
  in a motion nobody asked for.

Threads: goals execute on the action server's threads (one each, at most ``MAX_GOALS``); they wait on
the desk's replies and read the link's latest state, never on the node's executor.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from drone_contract.actions import ACTION_NAMES, GOTO, LAND, TAKEOFF, action_types
from drone_contract.messages import Command, CommandResult
from px4_link.telemetry import LocalPosition
from px4_link.vehicle import VehicleLink
from zenoh_robot import Node
from zenoh_robot.actions import ActionServer, CancelResponse, ServerGoalHandle

from .command_desk import CommandDesk

log = logging.getLogger("companion")

MAX_GOALS = 4                 # goals kept running at once per action (each holds a thread)
POLL_S = 0.2                  # feedback and progress checks, 5 Hz
GOTO_REACHED_M = 1.0          # PX4's acceptance radius (NAV_ACC_RAD's default is 2 m; the hold is tighter)
CLIMB_MS, CRUISE_MS = 0.5, 2.0   # slowest progress allowed before a goal is given up (never faster than PX4's)
SETTLE_S = 5.0                # the ACK -> the heartbeat showing the mode (PX4: 2 Hz + on change)
SLACK_S = 30.0                # plus this for every goal: spool-up, mode switches, a loaded machine


class Outcome(Exception):
    """The end of a goal other than success: ``status`` "abort" or "cancel", and the reason."""

    def __init__(self, status: str, message: str) -> None:
        super().__init__(message)
        self.status = status


class FlightActions:
    def __init__(self, node: Node, desk: CommandDesk, link: VehicleLink) -> None:
        self._desk, self._link = desk, link
        self.types = action_types()
        accept: Callable[[ServerGoalHandle], CancelResponse] = lambda _h: CancelResponse.ACCEPT  # noqa: E731
        self.servers: list[ActionServer] = [
            node.create_action_server(self.types.takeoff, ACTION_NAMES[TAKEOFF], self._takeoff,
                                      cancel_callback=accept, max_goals=MAX_GOALS),
            node.create_action_server(self.types.goto, ACTION_NAMES[GOTO], self._goto,
                                      cancel_callback=accept, max_goals=MAX_GOALS),
            node.create_action_server(self.types.land, ACTION_NAMES[LAND], self._land,
                                      cancel_callback=accept, max_goals=MAX_GOALS),
        ]

    def close(self) -> None:
        for server in self.servers:
            server.destroy()

    # -- the three executions (action server threads) ----------------------------------------------
    def _takeoff(self, handle: ServerGoalHandle) -> Any:
        goal, t = handle.request, self.types.takeoff
        target = float(goal.altitude_m)

        def result(ok: bool, message: str) -> Any:
            return t.Result(success=ok, message=message, altitude_m=self._altitude())

        def done() -> bool:
            alt = self._altitude()
            handle.publish_feedback(t.Feedback(altitude_m=alt, remaining_m=max(0.0, target - alt)))
            state = self._link.state
            mode = state.mode
            if not state.armed:   # PX4 takes AUTO.TAKEOFF disarmed too, and then never climbs
                raise Outcome("abort", f"takeoff: the drone is not armed (arm it first); mode {mode}")
            if mode == "AUTO.TAKEOFF":
                return False
            if mode == "AUTO.LOITER" and alt >= target - max(0.1 * target, 0.5):
                return True
            raise Outcome("abort", f"takeoff interrupted: mode {mode} at {alt:.1f} m")

        return self._run(handle, Command("takeoff", value=target, client_id=goal.client_id), done, result,
                         deadline_s=target / CLIMB_MS + SLACK_S, cancel=self._hold(goal.client_id),
                         settle=lambda: self._link.state.mode == "AUTO.TAKEOFF")

    def _goto(self, handle: ServerGoalHandle) -> Any:
        goal, t = handle.request, self.types.goto
        target = (float(goal.north_m), float(goal.east_m), float(goal.altitude_m))

        def result(ok: bool, message: str) -> Any:
            here = self._position()
            north, east, down = here if here is not None else (math.nan, math.nan, math.nan)
            return t.Result(success=ok, message=message, north_m=north, east_m=east, altitude_m=-down)

        start = self._position()
        distance0 = self._distance(start, target) if start is not None else math.inf

        def done() -> bool:
            here = self._position()
            state = self._link.state
            if here is None:
                return False
            left = self._distance(here, target)
            lp = self._link.telemetry.latest(LocalPosition)
            speed = math.hypot(lp.vx, lp.vy, lp.vz) if lp is not None else 0.0
            handle.publish_feedback(t.Feedback(distance_m=left, eta_s=left / speed if speed > 0.3 else math.inf))
            if not state.armed or state.mode != "AUTO.LOITER":
                raise Outcome("abort", f"goto interrupted: mode {state.mode}{'' if state.armed else ', disarmed'} "
                                       f"{left:.1f} m from the point")
            return left <= GOTO_REACHED_M

        deadline = (distance0 if math.isfinite(distance0) else 0.0) / CRUISE_MS + SLACK_S
        return self._run(handle, lambda: self._desk.goto(goal.client_id, *target), done, result,
                         deadline_s=deadline, cancel=lambda: self._desk.stop_goto(goal.client_id),
                         settle=lambda: self._link.state.mode == "AUTO.LOITER")   # from OFFBOARD: Hold first

    def _land(self, handle: ServerGoalHandle) -> Any:
        goal, t = handle.request, self.types.land

        def result(ok: bool, message: str) -> Any:
            return t.Result(success=ok, message=message, altitude_m=self._altitude())

        def done() -> bool:
            handle.publish_feedback(t.Feedback(altitude_m=self._altitude()))
            state = self._link.state
            if state.landed is True:
                return True
            if state.mode != "AUTO.LAND":
                raise Outcome("abort", f"landing interrupted: mode {state.mode} at {self._altitude():.1f} m")
            return False

        deadline = max(self._altitude(), 0.0) / CLIMB_MS + SLACK_S
        return self._run(handle, Command("land", client_id=goal.client_id), done, result, deadline_s=deadline,
                         cancel=self._hold(goal.client_id), settle=lambda: self._link.state.mode == "AUTO.LAND")

    # -- the shape every goal shares ---------------------------------------------------------------
    def _run(self, handle: ServerGoalHandle, command: Command | Callable[[], CommandResult | Future[CommandResult]],
             done: Callable[[], bool], result: Callable[[bool, str], Any], *, deadline_s: float,
             cancel: Callable[[], CommandResult | Future[CommandResult]],
             settle: Callable[[], bool] | None = None) -> Any:
        name = self._desk_name(command)
        reply = self._reply(self._desk.on_command(command) if isinstance(command, Command) else command())
        if not reply.success:
            handle.abort()
            return result(False, reply.message)
        # PX4 shows the new mode in its next heartbeat, after the ACK: wait for it before judging progress
        # (if it never shows, progress is judged on what PX4 says: a mode left at once aborts the goal).
        if settle is not None:
            self._link.wait_until(settle, SETTLE_S)
        until = time.monotonic() + deadline_s
        try:
            while True:
                if handle.is_cancel_requested:
                    stop = self._reply(cancel())
                    raise Outcome("cancel", f"{name} canceled: " + (stop.message if stop.success
                                                                   else f"hold refused: {stop.message}"))
                if done():
                    handle.succeed()
                    return result(True, f"{name} done: {reply.message}")
                if time.monotonic() > until:
                    raise Outcome("abort", f"{name} gave up after {deadline_s:.0f} s: no progress")
                time.sleep(POLL_S)
        except Outcome as end:
            log.warning("action %s: %s", name, end)
            (handle.canceled if end.status == "cancel" else handle.abort)()
            return result(False, str(end))

    @staticmethod
    def _desk_name(command: Command | Callable[..., Any]) -> str:
        return command.name if isinstance(command, Command) else "goto"

    def _hold(self, client: str) -> Callable[[], CommandResult | Future[CommandResult]]:
        return lambda: self._desk.on_command(Command("hold", client_id=client))

    def _reply(self, res: CommandResult | Future[CommandResult]) -> CommandResult:
        if isinstance(res, CommandResult):
            return res
        return res.result(timeout=CommandDesk.TIMEOUT_S + 5.0)

    def _position(self) -> tuple[float, float, float] | None:
        lp = self._link.telemetry.latest(LocalPosition)
        return None if lp is None else (lp.x, lp.y, lp.z)

    def _altitude(self) -> float:
        here = self._position()
        return -here[2] if here is not None else math.nan

    @staticmethod
    def _distance(here: tuple[float, float, float], target: tuple[float, float, float]) -> float:
        north, east, altitude = target
        return math.dist(here, (north, east, -altitude))
