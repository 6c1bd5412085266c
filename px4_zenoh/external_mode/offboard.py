"""``link.offboard`` flown through a PX4 external mode instead of OFFBOARD (``--px4-mode NAME``).

One job: keep px4_link's Offboard contract (validation, fence, velocity expiry, the 20 Hz repeat, the
``offboard_lost`` event, ``start``/``stop``) while PX4 is asked for the registered mode rather than OFFBOARD:
- ``start`` selects the mode (VEHICLE_CMD_SET_NAV_STATE with its nav_state, through the core's command
  sender and its ACK) and waits until vehicle_status shows it;
- each setpoint goes out as the mode's trajectory_setpoint, and only while the mode is active (selected and
  armed); no offboard_control_mode (an external mode needs none, and PX4 would count it as an OFFBOARD signal);
- PX4 leaving the mode by itself (its fallback, another GCS) is ``offboard_lost``, as leaving OFFBOARD is.
The mode is registered in the background (PX4 may not be there yet), again if PX4 loses it (a reboot), and
unregistered by ``close``.

With a mode executor (``install(executor=True)``, a fixed bridge only: executor.py) the mode's flight is one
step of the executor's sequence: ``start`` selects the mode and asks the executor to run (arm, take off, the
mode, RTL); PX4 leaving the mode for the executor's takeoff is not a loss; the GCS's ``rtl`` during the mode
ends the mode (mode_completed) and the executor flies RTL, still in charge; any other switch (hold, land, a
failsafe) is PX4's or the user's and ends the executor's turn, as PX4 rules.

``install_rtl`` registers the companion's own RTL as the replacement of PX4's (rtl.py).

Threading: as px4_link's Offboard; the registration runs on its own daemon thread.
"""
from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from px4_link.commands import CommandAck, CommandFailed, CommandTemporarilyRejected
from px4_link.offboard import PRESTREAM_S, VELOCITY_TIMEOUT_S
from px4_link.plugin import Event
from px4_link.targets import Geofence, PositionTarget, Target, TargetRefused
from px4_link.telemetry import LocalPosition, SysStatus

from ..convert import LANDED_ON_GROUND, mode_of
from ..core import ZenohCore
from ..offboard import ZenohOffboard
from .executor import ModeExecutor
from .messages import CMD_SET_NAV_STATE
from .mode import Check, ExternalMode
from .rtl import RETURN_ALT_M, ReturnHome

log = logging.getLogger(__name__)
RETRY_S = 2.0
# How long the check answers yes while the companion switches PX4 away from the mode it still flies: a "no" in
# that moment (the session has just ended) would make PX4 fail the mode (RTL) instead of taking the switch.
HANDOVER_S = 2.0
CHECKS_PERIOD_S = 0.1       # Commander.cpp runs its health and arming checks at 10 Hz
MODE_SHOWN_S = 1.0         # the executor's mode step: PX4's vehicle_status shows the mode within a status or two
POSITION_FRESH_S = 1.0     # an older local position is no position for the replacement RTL


class ModeOffboard(ZenohOffboard):
    def __init__(self, core: ZenohCore, geofence: Geofence | None, max_speed: float | None, mode: ExternalMode,
                 velocity_timeout_s: float = VELOCITY_TIMEOUT_S, executor: ModeExecutor | None = None) -> None:
        super().__init__(core, geofence, max_speed, velocity_timeout_s)
        self.mode = mode
        self.executor = executor
        self._stop = threading.Event()
        self._send_lock = threading.Lock()   # a send in progress ends before stop_stream returns
        self._handover_until = 0.0
        if executor is not None:
            executor.on_step = self._executor_step
        self._registrar = threading.Thread(target=self._keep_registered, name="px4mode-register", daemon=True)
        self._registrar.start()

    @property
    def mode_name(self) -> str:
        """What px4_link's state calls the mode (``EXTERNAL<n>``), "" before the registration."""
        mode_id = self.mode.mode_id
        return mode_of(mode_id) if mode_id >= 0 else ""

    @property
    def session_mode(self) -> str:
        return self.mode_name

    def stray(self) -> bool:
        ex = self.executor
        return super().stray() and not (ex is not None and ex.running)   # the executor hands the mode on itself

    def _keep_registered(self) -> None:
        self.mode.keep_registered(self._stop, RETRY_S)

    def _send(self, sp: Target, now: float) -> None:
        core = self._zcore
        if not core.can_send:
            return
        out = self.outgoing(sp, now)
        with self._send_lock:
            if not self._streaming:
                return      # stopped while this tick was on its way: nothing goes out after stop_stream
            ex = self.executor
            if ex is not None and ex.step == "takeoff":
                core.count("setpoints_withheld")   # PX4 flies the executor's takeoff, not the mode
                return
            if isinstance(out, PositionTarget):
                sent = self.mode.trajectory((out.x, out.y, out.z), None, out.yaw)
            else:
                sent = self.mode.trajectory(None, (out.vx, out.vy, out.vz), out.yaw)
        core.count("setpoints_sent" if sent else "setpoints_withheld")

    def _executor_step(self, what: str) -> None:
        """The executor's thread, before a step's command goes out: a send on its way ends first, so no setpoint
        of the mode reaches PX4 after the executor switched it away (rehearsal 21 counted one)."""
        with self._send_lock:
            pass

    def stop_stream(self) -> None:
        super().stop_stream()
        with self._send_lock:
            pass            # a send that passed its check before the stop has gone out: the caller may switch

    def start(self, prestream_s: float = PRESTREAM_S, confirm_timeout: float = 3.0) -> CommandAck:
        core = self._zcore
        with self._lock:
            if self.setpoint is None:
                raise TargetRefused("no_setpoint", "offboard.start needs a setpoint first (call set_setpoint)")
            if not self._streaming:
                self._streaming = True
        name = self.mode_name
        if not name:
            raise CommandTemporarilyRejected(CMD_SET_NAV_STATE, None,
                                             f"mode {self.mode.name!r} is not registered with PX4 (yet)")
        # PX4 arms into (and, armed, switches to) the mode only after its check said yes; the last answer may
        # predate what makes it yes now (a GCS took control a moment ago): the next one comes within ~310 ms.
        if not self.mode.wait(lambda: self.mode.verdict[0], confirm_timeout):
            raise CommandTemporarilyRejected(CMD_SET_NAV_STATE, None, f"mode {self.mode.name!r} cannot run yet: "
                                             + ", ".join(self.mode.verdict[1]))
        ack = self._select(confirm_timeout)
        if not core.wait_until(lambda: core.state.mode == name, confirm_timeout):
            raise CommandFailed(CMD_SET_NAV_STATE, ack.result,
                                f"mode {self.mode.name!r} ({name}) accepted but PX4 shows {core.state.mode}")
        if not core.state.armed:
            # PX4 folds the check's answers into its arming checks at 10 Hz: once its vehicle_status says the
            # selected mode can arm, an arm that follows is not refused for an answer PX4 has not read yet.
            core.wait_sample(SysStatus, confirm_timeout, lambda s: s.armable)
        self._active = True
        if self.executor is not None:
            self.executor.request()
        return ack

    def will_leave(self) -> None:
        self._handover_until = time.monotonic() + HANDOVER_S

    @property
    def handing_over(self) -> bool:
        """A switch away from the mode is under way (``will_leave``) while PX4 still flies it: the check answers
        yes, for at most HANDOVER_S, so PX4 takes the companion's switch rather than failing the mode."""
        return time.monotonic() < self._handover_until and self.mode.active

    def answer(self, check: Check) -> tuple[bool, Sequence[str]]:
        """The mode's arming check: ``check``'s verdict, but yes while handing over (rehearsal 26: the GCS's rtl
        ended the session, the next check said "no offboard session" before PX4 had taken the executor's RTL,
        and PX4's failsafe RTL took the executor out of charge)."""
        return (True, ()) if self.handing_over else check()

    def _select(self, timeout: float) -> CommandAck:
        """The switch to the mode. Armed, PX4 takes it only once its 10 Hz checks have read a yes from the mode's
        check, which may be a period behind the yes we sent: a refusal while our answer is yes is tried again."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                return self._zcore.send_command(CMD_SET_NAV_STATE, float(self.mode.mode_id))
            except CommandTemporarilyRejected:
                if time.monotonic() > deadline or not self.mode.verdict[0]:
                    raise
                time.sleep(CHECKS_PERIOD_S)

    def stop(self, mode: str | None = "AUTO.LOITER") -> CommandAck | None:
        """The GCS's rtl while the executor flies the mode: the mode is done (mode_completed), and the executor
        schedules RTL itself; anything else leaves the mode by a switch (a user's switch: PX4 puts the autopilot
        back in charge). Unlike OFFBOARD, the stream stops first: PX4 never fails an external mode for a pause
        in its setpoints (the companion's check answers for it), while a setpoint of ours that reached PX4
        after the switch would be flown against PX4's own flight task (CI stop 46 counted one). The same for the
        executor's completion: it switches PX4 away at once (rehearsal 16 counted one)."""
        self.will_leave()
        self.stop_stream()
        ex = self.executor
        if mode == "AUTO.RTL" and ex is not None and ex.running and ex.step == "mode":
            self.leaving = True
            try:
                # the executor has sent the mode's switch; PX4's status may not show it yet (an rtl 50 ms after
                # it was refused for "not active" in a rehearsal): the completion waits for the mode to fly
                self.mode.wait(lambda: self.mode.active or not ex.running, MODE_SHOWN_S)
                if not self.mode.complete(True):
                    raise CommandFailed(CMD_SET_NAV_STATE, None, f"mode {self.mode.name!r} is not active: "
                                        "its completion was not reported")
            finally:
                self._active = False
                self.leaving = False
            return None
        return super().stop(mode)

    def _on_mode_change(self, old: str, new: str) -> list[Event]:
        if not old or old != self.mode_name:
            return []
        ex = self.executor
        if ex is not None and ex.running and ex.step == "takeoff" and new == "AUTO.TAKEOFF":
            return []      # the executor's own step: the mode comes back after the takeoff
        lost = self._active and not self.leaving
        if not lost:
            return []
        self._active = False
        return [("offboard_lost", {"new_mode": new})]

    def summary(self) -> dict[str, Any]:
        reg = self.mode.registration
        out = {"name": self.mode.name, "nav_state": reg.mode_id if reg else None,
               "registered_in_s": round(reg.took_s, 4) if reg else None,
               "check_replies": self.mode.stats.replies_sent, "verdict": list(self.mode.verdict[1])}
        if self.executor is not None:
            out["executor"] = [what for _, what in self.executor.log]
        return out

    def close(self) -> None:
        if self.executor is not None:
            self.executor.close()
        self._stop.set()
        self._registrar.join(5.0)   # a registration in flight ends first, so close() unregisters it
        self.mode.close()


def install(link: Any, name: str, check: Check, *, replace_internal_mode: str | None = None,
            executor: bool = False) -> ModeOffboard:
    """Put a ModeOffboard on ``link`` (a Px4ZenohLink) in place of its OFFBOARD plugin; with ``executor`` the
    mode is owned by a mode executor (BridgeBugError on a PX4 whose bridge misroutes executor commands)."""
    core: ZenohCore = link.core
    mode = ExternalMode(core.session, name, check, domain=core.domain, replace_internal_mode=replace_internal_mode,
                        executor=executor)   # refused here, before the OFFBOARD plugin is touched
    old: ZenohOffboard = link.offboard
    old.stop_stream()
    new = ModeOffboard(core, old.geofence, old._validator.max_speed, mode, old.velocity_timeout_s,
                       ModeExecutor(mode) if executor else None)
    link.offboard = new
    mode.check = functools.partial(new.answer, check)
    core.add_mode_namer(_namer(mode, None))
    return new


def _namer(mode: ExternalMode, replaces: str | None) -> Callable[[int], tuple[str, str | None] | None]:
    """The state's name for ``mode`` while PX4 flies it (px4_zenoh has no AVAILABLE_MODES to read it from)."""
    def name(nav_state: int) -> tuple[str, str | None] | None:
        return (mode.name, replaces) if nav_state == mode.mode_id >= 0 else None
    return name


def install_rtl(link: Any, return_alt_m: float | None = None) -> ReturnHome:
    """Register the companion's RTL (rtl.py) as the replacement of PX4's, flown from ``link``'s telemetry."""
    core: ZenohCore = link.core

    def position() -> tuple[float, float, float] | None:
        p = core.latest(LocalPosition)
        if p is None or time.monotonic() - p.received_at > POSITION_FRESH_S:
            return None
        return (p.x, p.y, p.z)

    def landed() -> bool:
        return bool(core.state.landed_state == LANDED_ON_GROUND)
    rtl = ReturnHome(core.session, position, landed, domain=core.domain,
                     return_alt_m=RETURN_ALT_M if return_alt_m is None else return_alt_m)
    core.add_mode_namer(_namer(rtl.mode, "AUTO.RTL"))   # a GCS's rtl is confirmed by this mode flying
    return rtl
