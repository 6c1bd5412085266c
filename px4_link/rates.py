"""Delivered message rates, and the message intervals to ask for again after a PX4 reboot.

PX4 forgets MAV_CMD_SET_MESSAGE_INTERVAL requests when it reboots, and it delivers a
stream at the first sensor sample after the interval (200 Hz asked -> ~123 Hz in SITL), so
the companion needs both the measured rate and a link that re-asks on its own.
"""
from __future__ import annotations

import threading
import time
from collections import deque

MAX_SAMPLES_PER_TYPE = 4096   # bounds memory whatever a sender floods us with
MAX_TYPES = 256


class RateMeter:
    """Arrival times per message name, to measure the delivered rate over a window."""

    def __init__(self) -> None:
        self._arrivals: dict[str, deque[float]] = {}
        self._lock = threading.Lock()

    def record(self, name: str, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        with self._lock:
            q = self._arrivals.get(name)
            if q is None:
                if len(self._arrivals) >= MAX_TYPES:
                    return
                q = self._arrivals[name] = deque(maxlen=MAX_SAMPLES_PER_TYPE)
            q.append(now)

    def rate_hz(self, name: str, window: float = 2.0) -> float:
        """Messages per second over the last ``window`` s (0.0 if none)."""
        now = time.monotonic()
        with self._lock:
            q = self._arrivals.get(name.upper())
            if not q:
                return 0.0
            n = sum(1 for t in q if now - t <= window)
        return n / window


class BootWatch:
    """Spots a vehicle reboot from its boot clock going backwards (ATTITUDE, SYSTEM_TIME)."""

    # UDP reordering never moves time_boot_ms back this far, whatever the stream's rate: the
    # watch works as well on a companion's 10 Hz ATTITUDE as on PX4's default 100 Hz. Nor does
    # a slow rate delay the detection: a rebooted PX4 has forgotten the interval asked and
    # sends ATTITUDE at its default rate again (and SYSTEM_TIME at 1 Hz) from its first second.
    JUMP_MS = 250

    def __init__(self) -> None:
        self._last_ms: int | None = None

    def rebooted(self, time_boot_ms: int) -> bool:
        last, self._last_ms = self._last_ms, time_boot_ms
        return last is not None and time_boot_ms + self.JUMP_MS < last

    def reset(self) -> None:
        self._last_ms = None


class RequestedIntervals:
    """Message id -> Hz the user asked for, replayed after a reconnect or reboot."""

    def __init__(self) -> None:
        self._hz: dict[int, float] = {}
        self._lock = threading.Lock()

    def remember(self, msg_id: int, hz: float) -> None:
        with self._lock:
            self._hz[msg_id] = hz

    def items(self) -> list[tuple[int, float]]:
        with self._lock:
            return list(self._hz.items())
