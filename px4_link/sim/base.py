"""SimulatorBase: what a simulated PX4 is whatever protocol it speaks.

The MAVLink ``Simulator`` (simulator.py) and PX4's-Zenoh ``ZenohSimulator`` (px4_zenoh/sim) differ
only in their front end; the vehicle behind it is this one: the Commander's rules, Failsafes,
ParamStore, PointMassQuad and the fault schedule, stepped by one loop thread under one lock, and
the properties tests read from any thread. A subclass brings its loop (``_run``), its front end
(``_before_start``/``_after_stop``) and its records of setpoints and answered commands.
No protocol here: px4_link never imports Zenoh.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Self

import numpy as np

from .commander import (
    OFFBOARD_LOSS_LATENCY_S,
    ON_GROUND,
    PX4_ESTIMATOR_WARMUP_S,
    Commander,
    FailsafeEvent,
    ModeChange,
    ReceivedSetpoint,
)
from .failsafe import Failsafes
from .faults import EkfReset, EstimateLoss, EstimateRestored, Fault, FaultSchedule, LowBattery, Step
from .params import ParamStore
from .physics import PointMassQuad

# PX4 SITL's default home (Zurich), also what Gazebo/jMAVSim use.
DEFAULT_HOME = (47.397742, 8.545594, 488.0)

# Internal errors of every simulator in this process (a bug in the simulator, never PX4 behaviour):
# tests/conftest.py fails the test during which one was recorded.
INTERNAL_ERRORS: list[str] = []

MAX_STEPS_PER_WAKE = 20   # physics steps one wake-up catches up at most before resyncing


class SimulatorBase:
    """One simulated vehicle: its model and rules, its loop thread's lifecycle, its introspection."""

    THREAD_PREFIX: ClassVar[str] = "px4sim"
    ERROR_LABEL: ClassVar[str] = "sim"          # INTERNAL_ERRORS entries read "<label><sysid>: ..."
    JOIN_TIMEOUT_S: ClassVar[float] = 2.0
    _log: ClassVar[logging.Logger] = logging.getLogger(__name__)

    def __init__(self, sysid: int, *, params: dict[str, float | int] | None,
                 home: tuple[float, float, float], physics_hz: float, seed: int | None,
                 estimator_warmup_s: float = PX4_ESTIMATOR_WARMUP_S, faults: Sequence[Fault] = (),
                 offboard_loss_latency_s: float = OFFBOARD_LOSS_LATENCY_S) -> None:
        if not 1 <= sysid <= 255:
            raise ValueError("sysid must be 1..255")
        self.sysid = sysid
        self.home = home
        self.physics_dt = 1.0 / physics_hz
        self.params = ParamStore({**(params or {}), "MAV_SYS_ID": sysid})
        self.vehicle = PointMassQuad(np.random.default_rng(seed))
        self._boot = time.monotonic()
        # estimator_warmup_s: boot -> pre-arm checks pass (PX4 SITL: 4.1 s); shorten it only where
        # arming is not what is tested.
        self.commander = Commander(self.params, self.vehicle, self._boot, home_alt=home[2],
                                   home_latlon=(home[0], home[1]),
                                   estimator_warmup_s=estimator_warmup_s,
                                   offboard_loss_latency_s=offboard_loss_latency_s)
        self.failsafes = Failsafes(self.params, self.commander)
        self.commander.link_check = self.failsafes.arming_refusal
        # faults (sim/faults.py): times from the start of this simulator
        self.faults = FaultSchedule()
        for f in faults:
            self.faults.add(f, self._boot)
        self.internal_errors: list[str] = []
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- lifecycle
    def _run(self) -> None:
        raise NotImplementedError

    def _before_start(self) -> None:
        """Open what the loop thread needs from the caller's thread (the MAVLink socket)."""

    def _after_stop(self) -> None:
        """Release what ``_before_start`` opened, once the loop thread has ended."""

    def start(self) -> Self:
        if self._thread is None:
            self._before_start()
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=f"{self.THREAD_PREFIX}-{self.sysid}",
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.JOIN_TIMEOUT_S)
            self._thread = None
        self._after_stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def run_forever(self, duration: float | None = None) -> None:
        """Blocking run for the CLI; returns after ``duration`` s (None: never) or on stop()."""
        self.start()
        deadline = math.inf if duration is None else time.monotonic() + duration
        try:
            while not self._stop.wait(min(0.5, max(0.0, deadline - time.monotonic()))):
                if time.monotonic() >= deadline:
                    break
        finally:
            self.stop()

    # ---------------------------------------------------------------- physics (loop thread, under the lock)
    def _advance(self, now: float, next_phys: float) -> float:
        """Run the physics steps due by ``now`` (faults first); returns when the next one is due."""
        steps = 0
        while next_phys <= now and steps < MAX_STEPS_PER_WAKE:
            for step in self.faults.due(next_phys):
                self._apply(step)
            target = self.commander.update(next_phys)
            self.failsafes.update(next_phys, self.vehicle.pos, self.vehicle.battery.remaining)
            self.vehicle.step(self.physics_dt, target, self.commander.limits())
            next_phys += self.physics_dt
            steps += 1
        if next_phys <= now:  # far behind (process was stopped): resync
            next_phys = now + self.physics_dt
        return next_phys

    def _apply(self, step: Step) -> None:
        if isinstance(step, EstimateLoss):
            self.commander.estimate_lost = True
        elif isinstance(step, EstimateRestored):
            self.commander.estimate_lost = False
        elif isinstance(step, EkfReset):
            delta = np.array(step.jump, dtype=float)
            self.vehicle.reset_position(delta)
            self.commander.on_position_reset(delta)
        elif isinstance(step, LowBattery):
            self.vehicle.battery.set_level(step.level)

    def inject(self, fault: Fault) -> None:
        """Schedule ``fault`` with its time counted from now (0: at the next physics step)."""
        with self._lock:
            self.faults.add(fault, time.monotonic())

    def _internal_error(self, text: str) -> None:
        self._log.error("%s%d internal error: %s", self.ERROR_LABEL, self.sysid, text)
        self.internal_errors.append(text)
        INTERNAL_ERRORS.append(f"{self.ERROR_LABEL}{self.sysid}: {text}")

    # ---------------------------------------------------------------- the front end's records
    def _setpoint_record(self) -> list[tuple[float, tuple[float, float, float] | None]]:
        raise NotImplementedError

    def _command_record(self) -> list[tuple[float, int, int]]:
        raise NotImplementedError

    # ---------------------------------------------------------------- introspection (any thread)
    @property
    def boot_time(self) -> float:
        """time.monotonic() at PX4's boot (the origin of every timestamp it sends)."""
        return self._boot

    @property
    def faults_applied(self) -> list[tuple[float, Step]]:
        """(monotonic time, fault or its end) of every injected fault so far."""
        with self._lock:
            return list(self.faults.applied)

    @property
    def battery_remaining(self) -> float:
        return self.vehicle.battery.remaining

    @property
    def armable(self) -> bool:
        """PX4's pre-arm checks pass now."""
        return self.commander.armable()

    @property
    def mode(self) -> str:
        return self.commander.mode

    @property
    def armed(self) -> bool:
        return self.commander.armed

    @property
    def landed(self) -> bool:
        return self.commander.landed_state == ON_GROUND

    @property
    def landed_state(self) -> int:
        return self.commander.landed_state

    @property
    def position(self) -> tuple[float, float, float]:
        with self._lock:
            return tuple(float(v) for v in self.vehicle.pos)  # type: ignore[return-value]

    @property
    def velocity(self) -> tuple[float, float, float]:
        with self._lock:
            return tuple(float(v) for v in self.vehicle.vel)  # type: ignore[return-value]

    @property
    def altitude(self) -> float:
        return -self.position[2]

    @property
    def setpoints_received(self) -> int:
        return self.commander.setpoints_received

    @property
    def last_setpoint(self) -> ReceivedSetpoint | None:
        return self.commander.last_setpoint

    @property
    def setpoint_arrivals(self) -> list[tuple[float, tuple[float, float, float] | None]]:
        """(monotonic time the front end received it, position or None) of each position setpoint, oldest first."""
        with self._lock:
            return self._setpoint_record()

    @property
    def failsafe_log(self) -> list[FailsafeEvent]:
        """Every failsafe PX4's own logic triggered (cause, action)."""
        with self._lock:
            return list(self.commander.failsafe_log)

    @property
    def landed_at(self) -> float | None:
        """Monotonic time of the last disarm on the ground (None while flying / never)."""
        return self.commander.landed_at

    @property
    def setpoints_since_landed(self) -> int:
        """Setpoints received while disarmed after landing (a companion still streaming)."""
        return self.commander.setpoints_since_landed

    @property
    def mode_log(self) -> list[ModeChange]:
        with self._lock:
            return list(self.commander.mode_log)

    @property
    def command_log(self) -> list[tuple[float, int, int]]:
        """(monotonic time, command, result) of every command answered."""
        with self._lock:
            return self._command_record()

    def get_param(self, name: str) -> float | int:
        return self.params[name]

    def set_param(self, name: str, value: float | int) -> None:
        """In-process shortcut (tests): what a parameter protocol, where there is one, does too."""
        self.params.set(name, value)

    def wait_for(self, predicate: Callable[[Self], bool], timeout: float, interval: float = 0.02) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate(self):
                return True
            time.sleep(interval)
        return predicate(self)
