"""Where the GCS sends each drone: target planning, apart from any node or session.

Targets start where the drone is: until the drone's offboard session is active under this
GCS, the target follows the drone's reported position (climbing towards the altitude at
most ``MAX_LEAD_M`` ahead); once active, the pattern is flown relative to that anchor. So
a restarted GCS, or a resume after a failsafe hold anywhere, never asks for a jump. Each
drone has its own anchor.

Formations (gcs/formation.py): each drone has its own slot, and all fly one pattern clock
(``FormationClock``) from the shared origin shifted by their slots, so no two drones are
ever sent the same point; a drone far from its slot is led there at most ``MAX_LEAD_M``
ahead of where it is, and its target moves no faster than ``MAX_TARGET_SPEED``.

Path error: the horizontal distance from the drone to its own commanded path (its slot's
copy of the pattern), counted from the moment it first reached that path: the lead-in from
home to a far slot is a transit the GCS commands on purpose, not an error of the flight.

``TargetPlanner`` is one drone's planning: gcs/app.py's ``DroneView`` gives it the drone's
reported position and whether its session is active, and streams what it answers. It
imports neither Zenoh nor the node (tests/test_architecture.py), so its tests drive it with
a clock of their own (tests/wing/test_gcs_planner.py).
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from drone_contract.limits import GCS_MAX_LEAD_M, GCS_MAX_TARGET_SPEED_MS

from .formation import lead
from .patterns import PathPoint, make_pattern, path_distance

MAX_LEAD_M = GCS_MAX_LEAD_M      # within the companion's max_offset_m (drone_contract.limits)
MAX_TARGET_SPEED = GCS_MAX_TARGET_SPEED_MS   # within its max_speed
LEAD_DT_MAX_S = 1.0   # a longer pause leads no further: the drone's step check then measures from the vehicle
# A formation drone has reached its slot's path once its target is that path (no longer a lead towards it)
# and the drone is this close to it; its path error counts from then on.
PATH_JOIN_M = 1.0

Clock = Callable[[], float]
Position = tuple[float, float, float]


class FormationClock:
    """Seconds on the formation's shared clock, started by the first drone to fly."""

    def __init__(self, clock: Clock = time.monotonic) -> None:
        self._clock = clock
        self._t0: float | None = None

    def elapsed(self) -> float:
        now = self._clock()
        if self._t0 is None:
            self._t0 = now
        return now - self._t0


class TargetPlanner:
    """One drone's targets and its path error (see the module docstring)."""

    def __init__(self, pattern_name: str, *, altitude: float, size: float, speed: float, rate_hz: float,
                 formation: str = "none", slot: tuple[float, float] = (0.0, 0.0),
                 formation_clock: FormationClock | None = None, fly: bool = True,
                 clock: Clock = time.monotonic) -> None:
        self.pattern_name = pattern_name
        self.pattern = make_pattern(pattern_name, altitude, size, speed)
        self.altitude, self.size, self.rate_hz = altitude, size, rate_hz
        self.formation, self.slot = formation, slot
        self._clock = clock
        self._formation_clock = formation_clock if formation_clock is not None else FormationClock(clock)
        self.fly = fly                     # fly the pattern once the session is active
        # Set once a mission has sent LAND: nothing more to stream, and a stream into a landing drone
        # is only noise (the companion ends its session on LAND and ignores setpoints outside one).
        self.done = False
        self._hover: PathPoint | None = None
        self._anchor: PathPoint | None = None
        self._t0 = 0.0
        self._frozen: PathPoint | None = None
        self._led: PathPoint | None = None     # the last formation target
        self._led_at: float | None = None      # when it was planned (this planner's clock)
        self.on_path = False               # joined its path: errors count from here
        self._target_on_path = False       # the target is the path itself (formation: no longer led)
        self.max_path_error = 0.0
        self.path_error_sum = 0.0
        self.path_error_samples = 0

    @property
    def mean_path_error(self) -> float:
        return self.path_error_sum / self.path_error_samples if self.path_error_samples else float("nan")

    def target(self, position: Position | None, session_active: bool) -> PathPoint | None:
        """What to stream now, or None (no position known: nothing safe to send)."""
        if self.done:
            return None
        if self._frozen is not None:
            return self._frozen
        if position is None:
            return None
        x, y, z = position
        toward = self._toward(-abs(self.altitude), z)   # climb (or descend) from where it is
        if not session_active:
            self._anchor = self._led = self._led_at = None
            self.on_path = self._target_on_path = False
            self._hover = PathPoint(x, y, toward, self._hover.yaw if self._hover else 0.0)
            return self._hover
        if self._hover is None:
            self._hover = PathPoint(x, y, toward)
        if not self.fly:   # session active, pattern not started: hold x, y, keep climbing
            self._hover = PathPoint(self._hover.x, self._hover.y, toward, self._hover.yaw)
            return self._hover
        if self.formation != "none":
            return self._formation_target(x, y, z, self._hover)
        if self._anchor is None:
            self._anchor, self._t0 = self._hover, self._clock()
            self.on_path = self._target_on_path = True   # the pattern starts where the drone is
        p0, p = self.pattern(0.0), self.pattern(self._clock() - self._t0)
        return PathPoint(self._anchor.x + p.x - p0.x, self._anchor.y + p.y - p0.y, self._toward(p.z, z), p.yaw)

    def _formation_target(self, x: float, y: float, z: float, hover: PathPoint) -> PathPoint:
        # One clock for the whole formation; the slot shifts this drone's copy of the path.
        self._anchor = PathPoint(*self.slot, 0.0)
        p0, p = self.pattern(0.0), self.pattern(self._formation_clock.elapsed())
        px, py = self.slot[0] + p.x - p0.x, self.slot[1] + p.y - p0.y
        tx, ty = lead(x, y, px, py, MAX_LEAD_M)
        # Led from the last target, never faster than MAX_TARGET_SPEED over the time since it: no jump to refuse.
        # By the clock, not by the call: a late timer tick is followed at once by the next one (the executor
        # keeps the phase), and a step per call put two full steps 5-50 ms apart, which the drone's step
        # check refused as 10 m/s (4 of 10 drones of a loaded swarm sweep, 2026-11-29).
        now = self._clock()
        prev = self._led or hover
        dt = 1.0 / self.rate_hz if self._led_at is None else min(max(now - self._led_at, 0.0), LEAD_DT_MAX_S)
        tx, ty = lead(prev.x, prev.y, tx, ty, MAX_TARGET_SPEED * dt)
        self._led_at = now
        self._target_on_path = self._target_on_path or (tx, ty) == (px, py)
        self._led = PathPoint(tx, ty, self._toward(p.z, z), p.yaw)
        return self._led

    @staticmethod
    def _toward(z_target: float, z: float) -> float:
        """``z_target``, but at most MAX_LEAD_M above or below the drone's ``z``."""
        return min(max(z_target, z - MAX_LEAD_M), z + MAX_LEAD_M)

    def start_pattern(self) -> None:
        self.fly, self._anchor, self._frozen = True, None, None
        self.on_path = self._target_on_path = False

    def freeze(self, position: Position | None, session_active: bool) -> None:
        """Keep sending the current target (a jump back to the start would be refused)."""
        self._frozen = self.target(position, session_active)
        self.fly = False

    def track(self, position: Sequence[float], offboard: bool) -> None:
        """Counts the path error of a reported position (``offboard``: PX4 in OFFBOARD), once the target
        is the path itself."""
        if not offboard or self._anchor is None or not self._target_on_path or self.done:
            return
        # In the pattern's own frame: the path flown is anchor + p(t) - p(0).
        p0 = self.pattern(0.0)
        x, y = position[0] - self._anchor.x + p0.x, position[1] - self._anchor.y + p0.y
        err = path_distance(x, y, self.pattern_name, self.size)
        if not self.on_path and err > PATH_JOIN_M:
            return
        self.on_path = True
        self.max_path_error = max(self.max_path_error, err)
        self.path_error_sum += err
        self.path_error_samples += 1
