"""Who may steer the drone, and where a setpoint from the GCS goes.

A setpoint is admitted only from the GCS in control (control.py); while an offboard session is
open (starting, active or failsafe hold) only from the holder, ever: a session without a holder
admits nobody's, so no gap in control is a gap any streamer can fill. It is checked against what
the vehicle is doing now; inside an operator-requested offboard session it goes to px4_link's
stream (offboard_session.py), outside one it is kept as the sender's candidate, where an
``offboard_start`` begins. Every refusal is counted and reported as an event (rate-limited).

Latest wins: inside a session a setpoint older (by its source stamp, then sequence number) than
the holder's last forwarded one is never forwarded, only counted (``stale``): a delayed copy or a
sample recovered from the redundancy history after a fade must not turn the vehicle back towards
an older target. A session starts from the candidate's stamp, so a GCS whose clock stepped back
is held (its setpoints stale, the deadline failsafe HOLDs) until an operator starts a new session.

Threads: ``on_setpoint`` runs on the node's executor (any of its threads: the companion's is
multi-threaded); ``offboard_start`` on the PX4 worker. The candidates table is bounded
(a forger can invent client ids) and guarded by a lock; the stale check and the hand-off to the
session are one step under ``_forward_lock``, so two threads cannot forward out of order.
"""
from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drone_contract.commands import NO_SETPOINTS_YET
from drone_contract.messages import DroneSetpoint, valid_client_id
from px4_link.targets import PositionTarget, Target, TargetRefused, TargetValidator, VehicleMotion, VelocityTarget
from px4_link.telemetry import LocalPosition
from px4_link.vehicle import VehicleLink
from zenoh_robot.ratelimit import RateLimiter
from zenoh_robot.tools.stream_metrics import StreamRecorder

from .config import CompanionConfig
from .control import ControlArbiter
from .events import EventReporter
from .failsafe import DeadlineFailsafe
from .offboard_session import OffboardLifecycle, OffboardState
from .px4_worker import Px4Worker


@dataclass
class Candidate:
    """The latest setpoint from one client while no session forwards it: where offboard_start begins."""
    sp: Target | None
    at: float
    refused: str = ""        # why the latest one was refused, "" when it passed the checks
    stamp: tuple[int, int] = (0, 0)   # (source stamp ns, seq): where a session started from it begins


def to_target(msg: DroneSetpoint) -> Target:
    # NaN leaves the heading to PX4 (the message says so); an infinite yaw is no heading: refused.
    yaw = None if math.isnan(msg.yaw) else msg.yaw
    return (VelocityTarget(msg.x, msg.y, msg.z, yaw) if msg.is_velocity
            else PositionTarget(msg.x, msg.y, msg.z, yaw))


class SetpointGate:
    MAX_CANDIDATES = 16
    RESUME_EVERY_S = 3.0     # resume_on_setpoints: one attempt at a time, not one per setpoint

    def __init__(self, link: VehicleLink, control: ControlArbiter, lifecycle: OffboardLifecycle,
                 failsafe: DeadlineFailsafe, events: EventReporter, worker: Px4Worker,
                 config: Callable[[], CompanionConfig]) -> None:
        self._link, self._control, self._lifecycle = link, control, lifecycle
        self._failsafe, self._events, self._worker = failsafe, events, worker
        self._config = config             # live: a `param set` replaces the config
        self.received = StreamRecorder()
        self.rejected = 0
        self.rejected_by_reason: Counter[str] = Counter()   # refused after the control check, by reason
        self.ignored = 0                  # valid but outside a session: kept as candidate only
        self.stale = 0                    # older than the holder's last forwarded one: dropped (latest wins)
        # (client, source stamp ns, seq) of the last setpoint handed to the session (or its start).
        self._last_forwarded: tuple[str, int, int] | None = None
        self._forward_lock = threading.Lock()
        # The holder's refusals have a limiter of their own: the shared one is keyed by client id and
        # full (new keys counted, never reported) once a peer has forged enough ids.
        self._holder_reports = RateLimiter(interval=config().report_interval_s)
        self._candidates: dict[str, Candidate] = {}
        self._lock = threading.Lock()
        self._resume_tried = 0.0
        # Limits are passed to each check: max_offset_m and max_speed are live parameters.
        self.targets = TargetValidator(geofence=None, max_speed=None)
        self._flying = ""                 # whose setpoint px4_link streams: told when the fence cuts it
        link.add_event_listener(self._on_link_event)

    def on_setpoint(self, msg: DroneSetpoint, info: Any) -> None:
        self.received.record(info.seq, info.source_stamp_ns, info.received_stamp_ns)
        client = msg.client_id if valid_client_id(msg.client_id) else ""
        holder = self._control.holder
        session = self._lifecycle.state is not OffboardState.IDLE
        # Outside a session a setpoint with no holder is only kept as its sender's candidate.
        if not client or client != holder and (holder or session):
            _, why, _ = self._control.admit(client, "setpoint")
            self.rejected += 1
            self._events.refused("setpoint_rejected", client, "not_in_control", why)
            return
        self._control.seen(client)
        stamp = (info.source_stamp_ns, info.seq)
        if self._is_stale(client, stamp):
            self.stale += 1
            return
        now = time.monotonic()
        cfg = self._config()
        try:
            sp = to_target(msg)
            self.targets.check_against_vehicle(sp, self._motion(), cfg.max_offset_m, cfg.max_speed)
        except TargetRefused as exc:
            self._remember(client, None, now, f"{exc}")
            self._refuse(client, exc.reason, f"setpoint refused: {exc}")
            return
        self._remember(client, sp, now, "", stamp)
        try:
            with self._forward_lock:
                if self._is_stale(client, stamp):   # a newer one was forwarded meanwhile (another thread)
                    self.stale += 1
                    return
                self._lifecycle.forward(sp, stamp[0] / 1e9 if stamp[0] > 0 else None)
                self._last_forwarded = (client, *stamp)
        except TargetRefused as exc:
            if exc.reason == "no_session":   # valid, kept as the candidate, never sent
                self.ignored += 1
                self._events.refused("setpoint_ignored", client, exc.reason, str(exc))
                return
            # px4_link's own checks (geofence, step rate)
            self._remember(client, None, now, str(exc))
            self._refuse(client, exc.reason, f"setpoint refused: {exc}")
            return
        self._flying = client
        self._failsafe.fed(now)

    @property
    def last_forwarded(self) -> tuple[str, int, int] | None:
        """(client, source stamp ns, seq) of the target px4_link streams to PX4 now (None: none yet)."""
        return self._last_forwarded

    def on_superseded(self, pub_id: int, seq: int, source_stamp_ns: int, received_ns: int) -> None:
        """A setpoint recovered with a newer one (the subscription delivered only that): it reached the
        companion, so the record of arrivals keeps it; it is never forwarded."""
        self.received.record(seq, source_stamp_ns, received_ns)

    def _is_stale(self, client: str, stamp: tuple[int, int]) -> bool:
        """Inside a session: not newer than what this client last had forwarded."""
        last = self._last_forwarded
        return (last is not None and last[0] == client and self._lifecycle.in_session
                and stamp <= (last[1], last[2]))

    def _on_link_event(self, name: str, details: dict[str, Any]) -> None:   # px4_link's thread: never block
        """px4_link cut the velocity it streams at the fence, or let it expire: tell its sender."""
        if name == "setpoint_clamped":
            self.rejected += 1
            self._events.refused("setpoint_rejected", self._flying, str(details.get("reason", "geofence")),
                                 f"setpoint cut: {details.get('message', '')}")
        elif name == "setpoint_expired":
            self._events.event("setpoint_expired", str(details.get("message", "")), "zero velocity", self._flying)

    def _refuse(self, client: str, reason: str, detail: str) -> None:
        """Count a refused setpoint of a sender that passed the control check, and tell it why."""
        self.rejected += 1
        self.rejected_by_reason[reason] += 1
        if not client or client != self._control.holder:
            self._events.refused("setpoint_rejected", client, reason, detail)
            return
        self._holder_reports.interval = self._config().report_interval_s   # a live parameter
        count = self._holder_reports.hit(reason)
        if count:
            self._events.event("setpoint_rejected", detail, "refused", client, count)

    def _remember(self, client: str, sp: Target | None, now: float, refused: str,
                  stamp: tuple[int, int] = (0, 0)) -> None:
        with self._lock:
            if client not in self._candidates and len(self._candidates) >= self.MAX_CANDIDATES:
                oldest = min(self._candidates, key=lambda c: self._candidates[c].at)
                del self._candidates[oldest]
            self._candidates[client] = Candidate(sp, now, refused, stamp)
        if (not refused and self._config().resume_on_setpoints and client == self._control.holder
                and self._lifecycle.state is OffboardState.FAILSAFE_HOLD
                and now - self._resume_tried > self.RESUME_EVERY_S):
            self._resume_tried = now
            self._worker.submit_guarded("resume", lambda: self.offboard_start(client))

    def _motion(self) -> VehicleMotion | None:
        pos = self._link.telemetry.latest(LocalPosition)
        if pos is None or time.monotonic() - pos.received_at > 1.0:
            return None
        return VehicleMotion((pos.x, pos.y, pos.z), (pos.vx, pos.vy, pos.vz))

    def offboard_start(self, client: str) -> str:
        """Open a session from ``client``'s candidate (PX4 worker: waits for PX4's ACK)."""
        with self._lock:
            cand = self._candidates.get(client)
        now = time.monotonic()
        cfg = self._config()
        fresh = cand is not None and now - cand.at <= max(cfg.setpoint_deadline, 0.5)
        if cand is None or not fresh:
            raise TargetRefused("no_setpoints", f"{NO_SETPOINTS_YET} from {client}: stream setpoints (from the "
                                                "vehicle's position) before asking for OFFBOARD")
        if cand.sp is None:
            raise TargetRefused("setpoints_refused", f"setpoints refused: {cand.refused}")
        try:
            self.targets.check_against_vehicle(cand.sp, self._motion(), cfg.max_offset_m, cfg.max_speed)
        except TargetRefused as exc:
            raise TargetRefused(exc.reason, f"setpoints refused: {exc}") from None
        self._flying = client
        with self._forward_lock:    # the session begins at the candidate: nothing older follows it
            self._last_forwarded = (client, *cand.stamp)
        # The deadline counts from now before the session turns active too: the watchdog (and the PX4 mode's
        # check) must never read the last session's setpoint time against the new one.
        self._failsafe.rearm()
        self._lifecycle.start(cand.sp)
        self._failsafe.rearm()
        return self._link.offboard.session_mode or "OFFBOARD"
