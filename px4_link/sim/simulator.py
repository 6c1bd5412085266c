"""Simulator: one PX4-like vehicle on a UDP port, run by a single loop thread.

The loop sleeps in select() until the next physics step or telemetry message is due, so
it costs little CPU. Tests may read the introspection properties (mode, armed, position,
setpoints_received, mode_log, ...) from any thread; everything else goes over MAVLink.
"""
from __future__ import annotations

import logging
import select
import socket
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .commander import ON_GROUND, PX4_ESTIMATOR_WARMUP_S, Commander, FailsafeEvent, ModeChange, ReceivedSetpoint
from .failsafe import Failsafes
from .faults import EkfReset, EstimateLoss, EstimateRestored, Fault, FaultSchedule, LowBattery, Step
from .params import ParamStore
from .physics import PointMassQuad
from .protocol import SimProtocol, StreamTable

log = logging.getLogger(__name__)

# PX4 SITL's default home (Zurich), also what Gazebo/jMAVSim use.
DEFAULT_HOME = (47.397742, 8.545594, 488.0)

# Internal errors of every Simulator in this process (a bug in the simulator, never PX4 behaviour):
# tests/conftest.py fails the test during which one was recorded.
INTERNAL_ERRORS: list[str] = []


class Simulator:
    """A PX4-faithful MAVLink vehicle.

    ``port`` is our UDP source port (PX4 SITL: 14580; 0 = ephemeral, see ``.port`` after
    start), ``target_port`` where we send (PX4 SITL: 14540).
    """

    def __init__(self, sysid: int = 1, *, compid: int = 1, port: int = 14580,
                 target_port: int = 14540, target_host: str = "127.0.0.1",
                 bind_host: str = "127.0.0.1", params: dict[str, float | int] | None = None,
                 rates: dict[str, float] | None = None,
                 home: tuple[float, float, float] = DEFAULT_HOME, physics_hz: float = 100.0,
                 seed: int | None = None, estimator_warmup_s: float = PX4_ESTIMATOR_WARMUP_S,
                 faults: Sequence[Fault] = ()) -> None:
        if not 1 <= sysid <= 255:
            raise ValueError("sysid must be 1..255")
        self.sysid, self.compid = sysid, compid
        self._bind = (bind_host, port)
        self.target = (target_host, target_port)
        self.home = home
        self.physics_dt = 1.0 / physics_hz
        self.params = ParamStore({**(params or {}), "MAV_SYS_ID": sysid})
        self.streams = StreamTable(rates)
        self.vehicle = PointMassQuad(np.random.default_rng(seed))
        self._boot = time.monotonic()
        # estimator_warmup_s: boot -> pre-arm checks pass (PX4 SITL: 4.1 s); shorten it only where
        # arming is not what is tested.
        self.commander = Commander(self.params, self.vehicle, self._boot, home_alt=home[2],
                                   estimator_warmup_s=estimator_warmup_s)
        self.failsafes = Failsafes(self.params, self.commander)
        # faults (sim/faults.py): times from the start of this simulator
        self.faults = FaultSchedule()
        for f in faults:
            self.faults.add(f, self._boot)
        self.internal_errors: list[str] = []
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self.protocol: SimProtocol | None = None
        self.loop_iterations = 0

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> "Simulator":
        if self._thread is not None:
            return self
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(self._bind)
        sock.setblocking(False)
        self._sock = sock
        self.protocol = SimProtocol(sock, self.target, self.sysid, self.compid, self.commander,
                                    self.vehicle, self.params, self.streams, self.home,
                                    self._boot, on_log=lambda s: log.debug("sim%d: %s", self.sysid, s),
                                    on_internal_error=self._internal_error)
        self.protocol.on_heartbeat = self.failsafes.on_heartbeat
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"px4sim-{self.sysid}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "Simulator":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def run_forever(self) -> None:
        """Blocking run for the CLI (Ctrl-C / SIGTERM -> stop())."""
        self.start()
        try:
            while not self._stop.wait(0.5):
                pass
        finally:
            self.stop()

    # ---------------------------------------------------------------- loop
    def _run(self) -> None:
        proto = self.protocol
        assert proto is not None and self._sock is not None
        next_phys = time.monotonic()
        next_hb = next_phys
        readable = True
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                try:
                    if readable:   # most wake-ups are timers: a recvfrom raising EAGAIN costs as much as a step
                        proto.drain(now)
                    steps = 0
                    while next_phys <= now and steps < 20:
                        self._apply_faults(next_phys)
                        target = self.commander.update(next_phys)
                        self.failsafes.update(next_phys, self.vehicle.pos, self.vehicle.battery.remaining)
                        self.vehicle.step(self.physics_dt, target, self.commander.limits())
                        next_phys += self.physics_dt
                        steps += 1
                    if next_phys <= now:  # far behind (process was stopped): resync
                        next_phys = now + self.physics_dt
                    proto.flush_statustexts()
                    if now >= next_hb:
                        proto.heartbeat()
                        next_hb = now + 1.0
                    proto.send_commands()
                    proto.send_streams(now)
                except Exception:
                    self._internal_error(f"loop: {traceback.format_exc()}")
                self.loop_iterations += 1
            wake = min(next_phys, next_hb, self.streams.next_due() or next_phys)
            timeout = max(0.0, wake - time.monotonic())
            try:
                readable = bool(select.select([self._sock], [], [], timeout)[0])
            except (OSError, ValueError):
                break

    def _apply_faults(self, now: float) -> None:
        for step in self.faults.due(now):
            self._apply(step)

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

    @property
    def faults_applied(self) -> list[tuple[float, Step]]:
        """(monotonic time, fault or its end) of every injected fault so far."""
        with self._lock:
            return list(self.faults.applied)

    @property
    def gcs_connection_lost(self) -> bool:
        """PX4's vehicle_status.gcs_connection_lost: no MAV_TYPE_GCS heartbeat (true from boot)."""
        return self.failsafes.gcs_connection_lost

    @property
    def battery_remaining(self) -> float:
        return self.vehicle.battery.remaining

    def _internal_error(self, text: str) -> None:
        log.error("sim%d internal error: %s", self.sysid, text)
        self.internal_errors.append(text)
        INTERNAL_ERRORS.append(f"sim{self.sysid}: {text}")

    # ---------------------------------------------------------------- introspection
    @property
    def armable(self) -> bool:
        """PX4's pre-arm checks pass now (SYS_STATUS health PREARM_CHECK)."""
        return self.commander.armable()

    @property
    def port(self) -> int:
        """The UDP port we send from / listen on."""
        if self._sock is None:
            return self._bind[1]
        port: int = self._sock.getsockname()[1]
        return port

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
        """(monotonic time, position or None) of each SET_POSITION_TARGET_LOCAL_NED received, oldest first."""
        with self._lock:
            return list(self.protocol.setpoint_log) if self.protocol is not None else []

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
    def system_status(self) -> int:
        """HEARTBEAT system_status: 5 (CRITICAL) while a failsafe is active."""
        c = self.commander
        return 8 if c.mode == "TERMINATION" else 5 if c.failsafe else 4 if c.armed else 3

    @property
    def mode_log(self) -> list[ModeChange]:
        with self._lock:
            return list(self.commander.mode_log)

    @property
    def command_log(self) -> list[tuple[float, int, int]]:
        """(monotonic time, MAV_CMD, MAV_RESULT) of every command answered."""
        with self._lock:
            return list(self.protocol.stats.commands) if self.protocol else []

    @property
    def message_rates(self) -> dict[str, float]:
        """Rates requested (or default), Hz."""
        return dict(self.streams.rates)

    @property
    def not_simulated_intervals(self) -> dict[str, float]:
        """Intervals asked (us: -1 off, 0 default) for PX4 streams the simulator does not send."""
        return dict(self.streams.not_simulated_us)

    @property
    def delivered_rates(self) -> dict[str, float]:
        """Rates actually sent, Hz (sensor-sample quantised, as PX4 does)."""
        return {n: self.streams.delivered_hz(n) for n in self.streams.rates}

    @property
    def messages_sent(self) -> dict[str, int]:
        with self._lock:
            return dict(self.protocol.stats.sent_by_type) if self.protocol else {}

    @property
    def bad_frames_received(self) -> int:
        return self.protocol.stats.bad_frames if self.protocol else 0

    def get_param(self, name: str) -> float | int:
        return self.params[name]

    def set_param(self, name: str, value: float | int) -> None:
        """In-process shortcut (tests); the MAVLink PARAM_SET path does the same."""
        self.params.set(name, value)

    def wait_for(self, predicate: Callable[["Simulator"], bool], timeout: float,
                 interval: float = 0.02) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate(self):
                return True
            time.sleep(interval)
        return predicate(self)
