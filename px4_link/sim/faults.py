"""Faults a test (or ``--estimate-loss`` / ``--ekf-reset`` / ``--low-battery``) injects into the simulator.

Times are seconds after the simulator's start (``Simulator(faults=...)``, the CLI) or after the call
(``Simulator.inject``). What each fault does is what PX4 shows for it over MAVLink:
- ``EstimateLoss``: EKF2 loses its position estimate for ``duration`` s; modes that need a position
  cannot run and PX4's failsafe falls back (sim/failsafe.py);
- ``EkfReset``: an estimator reset moves the local frame by ``jump`` (NED m): LOCAL_POSITION_NED and
  GLOBAL_POSITION_INT jump (PX4 bumps ``xy_reset_counter`` in uORB; over MAVLink the jump is all the
  companion sees);
- ``LowBattery``: the pack reads ``level`` (0..1) from then on.

Threading: a schedule is built before the loop starts or under the simulator's lock; ``due`` runs on
the loop thread.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class EstimateLoss:
    at: float
    duration: float


@dataclass(frozen=True, slots=True)
class EkfReset:
    at: float
    jump: tuple[float, float, float]   # NED m


@dataclass(frozen=True, slots=True)
class LowBattery:
    at: float
    level: float   # state of charge, 0..1


Fault = EstimateLoss | EkfReset | LowBattery


@dataclass(frozen=True, slots=True)
class EstimateRestored:
    """The end of an EstimateLoss, scheduled by the schedule itself."""
    at: float


Step = Fault | EstimateRestored


class FaultSchedule:
    """Faults ordered by due time (monotonic seconds)."""

    def __init__(self) -> None:
        self._steps: list[tuple[float, Step]] = []
        self.applied: list[tuple[float, Step]] = []   # (monotonic time, step), for tests

    def add(self, fault: Fault, base: float) -> None:
        if not fault.at >= 0:
            raise ValueError(f"fault time must be >= 0: {fault}")
        self._steps.append((base + fault.at, fault))
        if isinstance(fault, EstimateLoss):
            if not fault.duration > 0:
                raise ValueError(f"estimate loss needs a duration > 0: {fault}")
            self._steps.append((base + fault.at + fault.duration, EstimateRestored(fault.at + fault.duration)))
        self._steps.sort(key=lambda s: s[0])

    def due(self, now: float) -> list[Step]:
        out = [s for t, s in self._steps if t <= now]
        if out:
            self._steps = [(t, s) for t, s in self._steps if t > now]
            self.applied += [(now, s) for s in out]
        return out

    def next_due(self) -> float | None:
        return self._steps[0][0] if self._steps else None


# ---------------------------------------------------------------- CLI
def _numbers(text: str, what: str, n_min: int, n_max: int) -> list[float]:
    try:
        values = [float(v) for v in text.replace(":", ",").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not n_min <= len(values) <= n_max:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return values


def parse_estimate_loss(text: str) -> EstimateLoss:
    """``AT:DURATION`` (s)."""
    at, duration = _numbers(text, "AT:DURATION", 2, 2)
    return EstimateLoss(at, duration)


def parse_ekf_reset(text: str) -> EkfReset:
    """``AT:NORTH[,EAST[,DOWN]]`` (s, m)."""
    at, *jump = _numbers(text, "AT:NORTH[,EAST[,DOWN]]", 2, 4)
    n, e, d = (jump + [0.0, 0.0])[:3]
    return EkfReset(at, (n, e, d))


def parse_low_battery(text: str) -> LowBattery:
    """``AT:LEVEL`` (s, fraction 0..1)."""
    at, level = _numbers(text, "AT:LEVEL", 2, 2)
    if not 0.0 <= level <= 1.0:
        raise argparse.ArgumentTypeError(f"battery level is a fraction 0..1, got {level}")
    return LowBattery(at, level)
