"""``link.offboard``: the validated setpoint stream and OFFBOARD entry/exit.

The plugin owns its stream: a periodic hook on the core's send thread repeats the latest
setpoint at the link's tick rate (``setpoint_rate_hz``), and a mode hook on the receive
thread tells a loss of OFFBOARD from our own switch away.

What is sent is decided on every send, not once when the target arrives:

- a position target is a place: it is checked against the fence when set and re-sent as is;
- a velocity target is a motion: on every send it is fenced from where the vehicle is then
  (``Geofence.fence_velocity``: its speed towards a boundary is cut to the speed from which
  the vehicle still stops before it), and it expires like PX4's own offboard timeout
  (COM_OF_LOSS_T, 1 s): a velocity not refreshed within ``velocity_timeout_s`` is replaced
  by zero velocity, so a sender that goes silent leaves the vehicle braking, not flying on.

Each cut and each expiry is counted (``setpoints_clamped``, ``setpoints_expired``) and
reported once per episode as an event (``setpoint_clamped`` with reason "geofence",
``setpoint_expired``); the episode ends when a target is sent uncut again (resp. refreshed).
"""
from __future__ import annotations

import threading
import time

from .action import set_mode
from .commands import CommandAck, CommandTemporarilyRejected
from .plugin import Core, Event
from .targets import (
    Geofence,
    PositionTarget,
    StoppingModel,
    Target,
    TargetRefused,
    TargetValidator,
    VelocityTarget,
    mavlink_fields,
)
from .telemetry import LocalPosition

# PX4's COM_OF_LOSS_T default: a velocity older than this is not what the sender wants now.
VELOCITY_TIMEOUT_S = 1.0
PRESTREAM_S = 0.1   # two ticks of the 20 Hz stream before OFFBOARD is asked
POSITION_MAX_AGE_S = 1.0   # older LOCAL_POSITION_NED is not where the vehicle is


class Offboard:
    """Setpoints are checked (finite, geofence, speed/jump) before anything is sent; the
    core's send thread repeats the latest one at ``setpoint_rate_hz`` through ``_tick``.

    Threads: ``set_setpoint`` on the caller's thread, ``_tick`` on the send thread; both
    send, and the episode flags they share are guarded by ``_lock``. ``geofence`` may be
    replaced at any time (one attribute, read once per send)."""

    def __init__(self, core: Core, geofence: Geofence | None, max_speed: float | None,
                 velocity_timeout_s: float = VELOCITY_TIMEOUT_S,
                 stopping: StoppingModel | None = None) -> None:
        self._core = core
        self._validator = TargetValidator(geofence, max_speed)
        self.velocity_timeout_s = velocity_timeout_s
        self.stopping = stopping or StoppingModel()
        self._lock = threading.Lock()
        self.setpoint: Target | None = None
        self._set_at = 0.0            # when ``setpoint`` was last set (refreshed) by the caller
        self._expired = False         # the velocity expired: zero velocity is being sent
        self._clamped = False         # the fence is cutting the velocity sent
        self._streaming = False
        self._stream_started: float | None = None
        self._active = False
        self.leaving = False   # set while we switch away ourselves: not an "offboard_lost"
        self._t0 = time.monotonic()   # time_boot_ms of our setpoints counts from here
        core.add_periodic(self._tick)
        core.add_mode_hook(self._on_mode_change)

    @property
    def geofence(self) -> Geofence | None:
        return self._validator.geofence

    @geofence.setter
    def geofence(self, fence: Geofence | None) -> None:
        """Replace the fence (e.g. a live parameter change): the next send obeys it."""
        self._validator.geofence = fence

    @property
    def streaming(self) -> bool:
        return self._streaming

    @property
    def is_active(self) -> bool:
        """True between a successful start() and stop() or PX4 leaving OFFBOARD."""
        return self._active

    @property
    def session_mode(self) -> str:
        """The PX4 mode ``start`` flies in (px4_zenoh's external mode flies in its own)."""
        return "OFFBOARD"

    def stray(self) -> bool:
        """PX4 flies the session's mode though nobody here asked (real PX4 goes back to OFFBOARD after
        landing and auto-disarm): outside a session the companion parks it in Hold."""
        return self._core.state.mode == self.session_mode

    def set_setpoint(self, sp: Target, sent_at: float | None = None) -> None:
        """Validate and stream ``sp``; the first one starts the stream. Raises
        TargetRefused (nothing is sent). ``sent_at``: the sender's time of ``sp`` in seconds, on its
        own clock (TargetValidator: a stream's spacing as sent, not only as it arrived)."""
        core = self._core
        now = time.monotonic()
        lp = self._fresh_position(now)
        vehicle_pos = lp.position if lp is not None else None
        try:
            self._validator.check(sp, now, vehicle_pos, sent_at)
        except TargetRefused as e:
            core.count("setpoints_rejected")
            core.emit("setpoint_rejected", {"setpoint": sp, "reason": e.reason, "message": str(e)})
            raise
        self._validator.accept(sp, now, sent_at)
        with self._lock:
            self.setpoint = sp
            self._set_at = now
            self._expired = False
            if not self._streaming:
                self._streaming = True
                self._stream_started = now
        self._send(sp, now)   # at once rather than at the next tick: setpoint age matters

    def stop_stream(self) -> None:
        """Stop streaming (the setpoint is kept). In OFFBOARD this makes PX4 fail safe
        after COM_OF_LOSS_T, which the link reports as ``offboard_lost``."""
        with self._lock:
            self._streaming = False
            self._stream_started = None

    def start(self, prestream_s: float = PRESTREAM_S, confirm_timeout: float = 3.0) -> CommandAck:
        """Stream, then OFFBOARD. PX4 needs no warm-up (commander/HealthAndArmingChecks/checks/
        offboardCheck.cpp: OFFBOARD is available once offboard_control_mode is recent), only one
        target that arrived: ``prestream_s`` lets two 20 Hz ticks go out, and a TEMPORARILY_REJECTED
        (the first target still on its way) is asked again every tick until ``confirm_timeout``."""
        with self._lock:
            if self.setpoint is None:
                raise TargetRefused("no_setpoint", "offboard.start needs a setpoint first "
                                                   "(call set_setpoint)")
            if not self._streaming:
                self._streaming = True
                self._stream_started = time.monotonic()
            started = self._stream_started or time.monotonic()
        wait = prestream_s - (time.monotonic() - started)
        if wait > 0:
            time.sleep(wait)
        give_up = time.monotonic() + confirm_timeout
        while True:
            try:
                ack = set_mode(self._core, "OFFBOARD", confirm_timeout)
                break
            except CommandTemporarilyRejected:
                if time.monotonic() + PRESTREAM_S > give_up:
                    raise
                time.sleep(PRESTREAM_S)
        self._active = True
        return ack

    def will_leave(self) -> None:
        """The caller is about to switch PX4 away from the session's mode (``stop``). OFFBOARD needs no notice:
        the stream runs until the switch (px4_zenoh's external mode holds its check's answer over the switch)."""

    def stop(self, mode: str | None = "AUTO.LOITER") -> CommandAck | None:
        """Leave OFFBOARD cleanly: switch to ``mode`` while still streaming (PX4 never sees
        a loss), then stop the stream. ``mode=None`` only stops the stream."""
        ack = None
        self.leaving = True
        try:
            if mode is not None and self._core.connected:
                ack = set_mode(self._core, mode)
        finally:
            self._active = False
            self.leaving = False
            self.stop_stream()
        return ack

    def _on_mode_change(self, old: str, new: str) -> list[Event]:
        """Mode hook (receive thread): PX4 leaving OFFBOARD while we did not ask is a loss."""
        if old != "OFFBOARD":
            return []
        lost = self._active and not self.leaving
        if not lost:
            return []
        self._active = False
        return [("offboard_lost", {"new_mode": new})]

    def _tick(self) -> None:
        """Periodic hook (send thread): repeat the latest setpoint while streaming."""
        sp = self.setpoint
        if self._streaming and sp is not None:
            self._send(sp, time.monotonic())

    def _fresh_position(self, now: float) -> LocalPosition | None:
        lp = self._core.latest(LocalPosition)
        return lp if lp is not None and now - lp.received_at < POSITION_MAX_AGE_S else None

    def outgoing(self, sp: Target, now: float) -> Target:
        """What goes to PX4 for ``sp`` now: a position as is; a velocity zeroed when expired,
        then fenced from the vehicle's latest position. Starts and ends the episodes (counts
        and emits on the calling thread)."""
        if isinstance(sp, PositionTarget):
            return sp
        events: list[Event] = []
        with self._lock:
            age = now - self._set_at
            if age > self.velocity_timeout_s:
                if not self._expired:
                    self._expired = True
                    events.append(("setpoint_expired", {
                        "setpoint": sp, "age_s": age, "message":
                        f"velocity target {sp} not refreshed for {age:.1f} s "
                        f"(> {self.velocity_timeout_s:g} s): zero velocity sent"}))
                sp = VelocityTarget(0.0, 0.0, 0.0, sp.yaw)
        fence = self._validator.geofence
        sent: Target = sp
        why: str | None = None
        if fence is not None:
            lp = self._fresh_position(now)
            if lp is None:   # cannot be fenced: brake rather than fly blind
                sent = VelocityTarget(0.0, 0.0, 0.0, sp.yaw)
                if sp.speed > 0.0:
                    why = "vehicle position unknown (no LOCAL_POSITION_NED for 1 s): zero velocity sent"
            else:   # where it is now, not where it was when PX4 said so
                age = now - lp.received_at
                here = (lp.x + lp.vx * age, lp.y + lp.vy * age, lp.z + lp.vz * age)
                sent, why = fence.fence_velocity(sp, here, self.stopping)
        with self._lock:
            start = why is not None and not self._clamped
            self._clamped = why is not None
        if start:
            events.append(("setpoint_clamped", {"setpoint": sp, "sent": sent, "reason": "geofence",
                                                "message": f"velocity target {_fmt(sp)} m/s cut by the geofence: "
                                                           f"{why}"}))
        for name, details in events:
            self._core.count("setpoints_expired" if name == "setpoint_expired" else "setpoints_clamped")
            self._core.emit(name, details)
        return sent

    def _send(self, sp: Target, now: float) -> None:
        core = self._core
        if not core.can_send:
            return
        sp = self.outgoing(sp, now)
        sysid, compid = core.vehicle_ids()
        boot_ms = int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF
        core.send_message(core.encoder().set_position_target_local_ned_encode(
            boot_ms, sysid, compid, **mavlink_fields(sp)))
        core.count("setpoints_sent")


def _fmt(sp: VelocityTarget) -> str:
    return "(" + ", ".join(f"{v:.1f}" for v in (sp.vx, sp.vy, sp.vz)) + ")"
