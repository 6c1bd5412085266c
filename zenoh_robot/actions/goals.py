"""A server's goals: who is running, what finished (until its result expires), and every decision
on a goal id, so a resent goal gets the first answer and never runs twice.

Bounded three ways: at most ``max_goals`` goals active at once (more are rejected), at most
``max_results`` finished goals kept (oldest forgotten first) and none past ``result_timeout``
(rcl_action's), and at most :data:`MAX_DECISIONS` remembered goal ids. Not thread safe by itself:
the server holds its lock around every call.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from .types import ACTIVE, TERMINAL, GoalStatus

MAX_DECISIONS = 4096     # goal ids whose acceptance or rejection is remembered (a resend gets the same)


@dataclass
class Goal:
    """One accepted goal: its handle (``ServerGoalHandle``), when it finished, its result when it has one."""
    goal_id: bytes
    stamp: tuple[int, int]
    handle: Any
    result: Future[Any] = field(default_factory=Future)
    finished_at: float | None = None

    @property
    def status(self) -> GoalStatus:
        return GoalStatus(self.handle.status)


class GoalTable:
    def __init__(self, max_goals: int, max_results: int, result_timeout: float) -> None:
        if max_goals < 1 or max_results < 1:
            raise ValueError(f"max_goals and max_results must be >= 1, got {max_goals}, {max_results}")
        if not result_timeout > 0:
            raise ValueError(f"result_timeout must be > 0 seconds, got {result_timeout!r}")
        self.max_goals = max_goals
        self.max_results = max_results
        self.result_timeout = result_timeout
        self._goals: OrderedDict[bytes, Goal] = OrderedDict()
        self._decisions: OrderedDict[bytes, tuple[bool, tuple[int, int]]] = OrderedDict()
        self.expired = 0

    def __iter__(self) -> Iterator[Goal]:
        return iter(list(self._goals.values()))

    def __len__(self) -> int:
        return len(self._goals)

    def get(self, goal_id: bytes) -> Goal | None:
        return self._goals.get(goal_id)

    def decision(self, goal_id: bytes) -> tuple[bool, tuple[int, int]] | None:
        """(accepted, stamp) given to this goal id before, or None for a new one."""
        return self._decisions.get(goal_id)

    def decide(self, goal_id: bytes, accepted: bool, stamp: tuple[int, int]) -> None:
        self._decisions[goal_id] = (accepted, stamp)
        while len(self._decisions) > MAX_DECISIONS:
            self._decisions.popitem(last=False)

    def active(self) -> int:
        return sum(1 for g in self._goals.values() if g.status in ACTIVE)

    def full(self) -> bool:
        return self.active() >= self.max_goals

    def add(self, goal: Goal) -> None:
        self._goals[goal.goal_id] = goal

    def finished(self, goal: Goal) -> None:
        goal.finished_at = time.monotonic()

    def expire(self) -> bool:
        """Forget finished goals past the result timeout, and the oldest beyond ``max_results``;
        whether any went (the status array changes)."""
        now = time.monotonic()
        done = [g for g in self._goals.values() if g.finished_at is not None and g.status in TERMINAL]
        gone = [g for g in done if now - (g.finished_at or now) > self.result_timeout]
        survivors = [g for g in done if g not in gone]
        if len(survivors) > self.max_results:
            survivors.sort(key=lambda g: g.finished_at or now)
            gone += survivors[:len(survivors) - self.max_results]
        for g in gone:
            self._goals.pop(g.goal_id, None)
        self.expired += len(gone)
        return bool(gone)
