"""The companion's ``command`` service: who may command the drone, what is allowed, and who does it.

A command passes three gates, in order: it is one of the contract's (``drone_contract.commands``);
its sender holds control or claims it (the ControlArbiter; ``take_control``, ``hand_over`` and a
``release_control`` outside an offboard session are answered here, without PX4); the one policy
(``command_policy``) allows it whoever sends it. Then its handler, from the table keyed by
``CommandName``, runs on the PX4 worker and the reply waits for it.
Every command is logged with its sender and every refusal says why.

Control never lapses in the air: a ``release_control`` during an offboard session (starting,
active or failsafe hold) puts the drone in HOLD on the PX4 worker first, then releases; a
``hand_over`` (or a ``release_control`` naming a GCS) offers control to that GCS, the holder keeping
it until the named GCS confirms with ``take_control``; ``watch_control`` (the companion's watchdog)
withdraws an offer nobody confirmed, holding the drone when its holder has left, and releases a
gone holder only on the ground. Every change is a ``control_changed`` event.

Threads: ``on_command`` runs on the node's executor and never waits for PX4: a command for PX4
goes to the worker's bounded command lane (full: refused at once, "busy") and the reply is a
future the service answers when the handler is done, or after ``TIMEOUT_S`` (then the command is
abandoned: it never starts later, px4_link withdraws its PX4 command). The executor stays free
for setpoints and the watchdog. Handlers run on the PX4 worker's command lane, one at a time;
``watch_control`` on the executor.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from drone_contract.commands import COMMAND_SPECS, COMMANDS, CommandName, command_name
from drone_contract.messages import Command, CommandResult, valid_client_id
from px4_link.commands import CommandError
from px4_link.targets import TargetRefused
from px4_link.telemetry import GlobalPosition, LocalPosition
from px4_link.vehicle import VehicleLink

from .config import CompanionConfig
from .control import ControlArbiter, HandOver
from .events import EventReporter
from .failsafe import DeadlineFailsafe
from .offboard_session import SAFE_MODE, OffboardLifecycle, OffboardState
from .px4_params import px4_param_refusal
from .px4_worker import CommandAbandoned, Px4Worker, WorkerBusy
from .setpoint_gate import SetpointGate

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had

Handler = Callable[[Command], str | None]   # runs on the PX4 worker; a str is the reply's message
EARTH_RADIUS_M = 6378137.0     # WGS-84 equatorial radius: PX4's own flat-earth projection (lib/geo)


def command_policy(cmd: Command, config: CompanionConfig, landed: bool | None) -> str:
    """Why ``cmd`` is not allowed whoever sends it, or ""."""
    if cmd.name == CommandName.TAKEOFF and not (0.5 <= (cmd.value or 5.0) <= 120):
        return f"takeoff altitude {cmd.value} m outside 0.5..120"
    if cmd.name == CommandName.DISARM and cmd.force and not landed and not config.allow_force_disarm:
        return ("forced disarm refused: the vehicle is not landed (motors would stop in flight); "
                "the companion allows it only with --allow-force-disarm")
    if cmd.name == CommandName.SET_PARAM:
        if cmd.text not in config.param_allow:
            return (f"set_param {cmd.text[:32]!r} refused: not in the companion's allow-list "
                    f"({', '.join(config.param_allow) or 'empty'})")
        if not math.isfinite(cmd.value):
            return f"set_param {cmd.text}: value {cmd.value} is not finite"
        return px4_param_refusal(cmd.text, cmd.value)
    return ""


class CommandDesk:
    TIMEOUT_S = 20.0
    # Answered by the control claim itself, never by PX4.
    CONTROL_ONLY = (CommandName.TAKE_CONTROL, CommandName.HAND_OVER)

    def __init__(self, link: VehicleLink, control: ControlArbiter, lifecycle: OffboardLifecycle,
                 gate: SetpointGate, failsafe: DeadlineFailsafe, events: EventReporter, worker: Px4Worker,
                 config: Callable[[], CompanionConfig]) -> None:
        self._link, self._control, self._lifecycle, self._gate = link, control, lifecycle, gate
        self._failsafe, self._events, self._worker = failsafe, events, worker
        self._config = config             # live: a `param set` replaces the config
        self.refused = 0
        self._handlers: dict[CommandName, Handler] = {
            CommandName.ARM: self._arm,
            CommandName.DISARM: self._disarm,
            CommandName.TAKEOFF: self._takeoff,
            CommandName.LAND: self._leave_for("AUTO.LAND"),
            CommandName.HOLD: self._leave_for("AUTO.LOITER"),
            CommandName.RTL: self._leave_for("AUTO.RTL"),
            CommandName.OFFBOARD_STOP: self._leave_for("AUTO.LOITER"),
            CommandName.OFFBOARD_START: lambda cmd: self._gate.offboard_start(cmd.client_id),
            CommandName.SET_PARAM: self._set_param,
            CommandName.RELEASE_CONTROL: self._release_holding,   # only during a session: HOLD first
        }
        unanswered = set(COMMAND_SPECS) - set(self._handlers) - set(self.CONTROL_ONLY)
        if unanswered:   # a command added to the contract must get a handler here
            raise RuntimeError(f"commands without a handler: {sorted(unanswered)}")

    def on_command(self, cmd: Command) -> CommandResult | Future[CommandResult]:
        who = cmd.client_id if valid_client_id(cmd.client_id) else f"<invalid {cmd.client_id[:64]!r}>"
        log.info("command %s (value=%g text=%r force=%s) from %s", cmd.name[:32], cmd.value, cmd.text[:32],
                 cmd.force, who)
        res = self._decide(cmd)
        if isinstance(res, Future):
            res.add_done_callback(lambda done: self._log_failure(cmd, who, done.result()))
        else:
            self._log_failure(cmd, who, res)
        return res

    @staticmethod
    def _log_failure(cmd: Command, who: str, res: CommandResult) -> None:
        if not res.success:
            log.warning("command %s from %s refused or failed: %s", cmd.name[:32], who, res.message)

    def _result(self, ok: bool, message: str) -> CommandResult:
        return CommandResult(ok, message, self._link.state.mode)

    def _refuse(self, why: str) -> CommandResult:
        self.refused += 1
        return self._result(False, why)

    def _decide(self, cmd: Command) -> CommandResult | Future[CommandResult]:
        name = command_name(cmd.name)
        if name is None:
            return self._refuse(f"unknown command {cmd.name[:32]!r}; commands: {', '.join(COMMANDS)}")
        client = cmd.client_id
        if name is CommandName.HAND_OVER or name is CommandName.RELEASE_CONTROL and cmd.text:
            return self._hand_over(client, cmd.text, leaving=name is CommandName.RELEASE_CONTROL)
        if name is CommandName.RELEASE_CONTROL:
            if self._control.holder != client or not client:
                return self._refuse(f"release_control refused: {client or '<none>'} does not hold control "
                                    f"(holder: {self._control.holder or 'none'})")
            if not self._session_open:
                self._control.release(client)
                self._events.event("control_changed", f"{client} released control", "no GCS in control", client)
                return self._result(True, "control released")
            # In a session: the PX4 worker holds the drone, then releases (_release_holding).
        if name is CommandName.TAKE_CONTROL and not cmd.force:
            previous = self._control.accept(client)
            if previous:
                self._events.event("control_changed", f"{client} took control from {previous} (hand-over confirmed)",
                                   f"{client} in control", previous)
                return self._result(True, f"{client} in control (handed over by {previous})")
        ok, why, previous = self._control.admit(client, name, claim=True,
                                                force=cmd.force and name is CommandName.TAKE_CONTROL)
        if not ok:
            self._events.refused("control_refused", client if valid_client_id(client) else "", name,
                                 f"command {name} from {client or '<no id>'}: {why}")
            return self._refuse(why)
        if previous:
            self._events.event("control_lost", f"{client} took control from {previous}", "", previous)
        if name is CommandName.TAKE_CONTROL:
            return self._result(True, f"{client} in control" + (f" (taken from {previous})" if previous else ""))
        why = command_policy(cmd, self._config(), self._link.state.landed)
        if why:
            return self._refuse(why)
        handler = self._handlers[name]
        return self._submit(name.value, client, lambda: handler(cmd))

    def _submit(self, what: str, client: str, work: Callable[[], str | None]) -> CommandResult | Future[CommandResult]:
        """``work`` on the PX4 worker's command lane; the reply when it is done (or refused at once: busy)."""
        try:
            job = self._worker.submit(what, work, self.TIMEOUT_S)
        except WorkerBusy as exc:
            self._events.refused("command_refused", client if valid_client_id(client) else "", "busy",
                                 f"command {what} from {client}: busy: {exc}")
            return self._refuse(f"busy: {exc}")
        reply: Future[CommandResult] = Future()
        job.add_done_callback(lambda done: reply.set_result(self._outcome(done)))
        return reply

    def goto(self, client: str, north: float, east: float, altitude: float) -> CommandResult | Future[CommandResult]:
        """The goto action's command (flight_actions.py): the control gate of every command, then the
        companion's geofence and a flying drone, then PX4's DO_REPOSITION on the worker."""
        who = client if valid_client_id(client) else f"<invalid {client[:64]!r}>"
        log.info("goto N %.1f E %.1f at %.1f m from %s", north, east, altitude, who)
        ok, why, previous = self._control.admit(client, "goto", claim=True)
        if not ok:
            self._events.refused("control_refused", client if valid_client_id(client) else "", "goto",
                                 f"goto from {client or '<no id>'}: {why}")
            return self._refuse(why)
        if previous:
            self._events.event("control_lost", f"{client} took control from {previous}", "", previous)
        why = self._goto_policy(north, east, altitude)
        if why:
            log.warning("goto from %s refused: %s", who, why)
            return self._refuse(why)
        return self._submit("goto", client, lambda: self._goto(client, north, east, altitude))

    def stop_goto(self, client: str) -> CommandResult | Future[CommandResult]:
        """A canceled goto: hold where the drone is now (a switch to Hold would keep flying to the point)."""
        ok, why, _ = self._control.admit(client, "goto cancel")
        if not ok:
            return self._refuse(why)
        return self._submit("goto cancel", client, self._hold_here)

    def _goto_policy(self, north: float, east: float, altitude: float) -> str:
        if not all(math.isfinite(v) for v in (north, east, altitude)):
            return f"goto refused: non-finite target ({north}, {east}, {altitude})"
        if not 0.5 <= altitude <= 120:
            return f"goto refused: altitude {altitude:g} m outside 0.5..120"
        outside = self._config().geofence().violation(north, east, -altitude)
        if outside:
            return f"goto refused: the target is outside the geofence: {outside}"
        vehicle = self._link.state
        if not vehicle.armed or vehicle.landed is not False:
            return "goto refused: the drone is not flying (take off first)"
        return ""

    def _outcome(self, done: Future[Any]) -> CommandResult:
        """The reply for a finished (or abandoned) handler: on the thread that settled it, so short."""
        try:
            msg = done.result()
        except (CommandError, TargetRefused, CommandAbandoned) as exc:
            return self._result(False, str(exc))
        except Exception as exc:  # noqa: BLE001  (a bad argument, a link that is down: the sender hears it)
            return self._result(False, f"{type(exc).__name__}: {exc}")
        return self._result(True, msg if isinstance(msg, str) and msg else "done")

    # -- control that never lapses in the air ------------------------------------------
    @property
    def _session_open(self) -> bool:
        return self._lifecycle.state is not OffboardState.IDLE

    def _hand_over(self, client: str, target: str, *, leaving: bool) -> CommandResult:
        ok, why = self._control.offer_to(client, target, leaving=leaving)
        if not ok:
            self._events.refused("control_refused", client if valid_client_id(client) else "", "hand_over", why)
            return self._refuse(why)
        offer = self._control.offer
        wait = max(0.0, offer.until - time.monotonic()) if offer is not None else 0.0
        detail = (f"{client} offers control to {target}: {target} confirms with take_control within {wait:.0f} s; "
                  f"{client} stays in control until then")
        self._events.event("control_changed", detail, "hand-over offered", target)
        return self._result(True, f"hand-over offered to {target} ({wait:.0f} s to confirm with take_control); "
                                  f"{client} stays in control until then")

    def watch_control(self, now: float) -> None:
        """The watchdog's control checks (executor): offers nobody confirmed, holders that are gone."""
        offer = self._control.expire_offer(now)
        if offer is not None:
            self._offer_expired(offer, now)
        vehicle = self._link.state
        # Unknown landed state while armed counts as flying: the safe side.
        grounded = not self._session_open and (not vehicle.armed or vehicle.landed is True)
        gone = self._control.expire(now, may_release=grounded)
        if gone is None:
            return
        if gone.released:
            self._events.event("control_changed", f"{gone.holder} released: liveliness lost", "no GCS in control",
                               gone.holder)
        else:
            self._events.event("control_changed", f"{gone.holder} gone (no liveliness token, silent "
                                                  f"{gone.silent_s:.1f} s) while the vehicle is not on the ground",
                               f"{gone.holder} stays in control", gone.holder)

    def _offer_expired(self, offer: HandOver, now: float) -> None:
        left = offer.leaving or self._control.gone(offer.holder, now)
        if self._control.holder != offer.holder:
            return
        self._events.event("control_changed", f"hand-over from {offer.holder} to {offer.target} not confirmed "
                                              f"in time", f"{offer.holder} stays in control" if not left else
                           f"{offer.holder} has left: HOLD", offer.target)
        if left:
            # A drone whose holder has left must hold now, not after the command in flight.
            self._worker.submit_failsafe("hand_over_expired",
                                         lambda: self._hold_and_release(offer.holder, offer.leaving), preempt=True)

    def _hold_and_release(self, client: str, release: bool) -> None:
        """PX4 worker: HOLD when a session is open; release when ``client`` asked to (it still holds)."""
        if self._control.holder != client:
            return   # someone took over meanwhile: theirs now
        if self._session_open:
            self._failsafe.clear()
            self._lifecycle.leave(SAFE_MODE, f"{client} left control")
        if release and self._control.release(client):
            self._events.event("control_changed", f"{client} released control", f"HOLD ({SAFE_MODE}) first; "
                                                                                 "no GCS in control", client)

    # -- handlers (PX4 worker) -----------------------------------------------------------
    def _release_holding(self, cmd: Command) -> str:
        client = cmd.client_id
        if self._control.holder != client:
            raise CommandError(0, None, f"release_control: {client} no longer holds control "
                                        f"(holder: {self._control.holder or 'none'})")
        held = self._session_open
        if held:
            self._failsafe.clear()
            self._lifecycle.leave(SAFE_MODE, f"release_control by {client}")
        self._control.release(client)
        self._events.event("control_changed", f"{client} released control" + (" during an offboard session" if held
                                                                              else ""),
                           f"HOLD ({SAFE_MODE}) first; no GCS in control" if held else "no GCS in control", client)
        return f"control released (the drone holds: {SAFE_MODE})" if held else "control released"

    def _leave_for(self, mode: str) -> Handler:
        def leave(cmd: Command) -> None:
            self._failsafe.clear()
            self._lifecycle.leave(mode, f"{cmd.name} by {cmd.client_id}")
        return leave

    def _arm(self, cmd: Command) -> str:
        # Arming must never take off by itself: PX4 sitting in OFFBOARD outside a session
        # (it returns there after landing) goes to Hold first.
        note = ""
        if self._link.offboard.stray() and not self._lifecycle.in_session:
            self._lifecycle.park("arm outside an offboard session")
            note = f"PX4 was in {self._link.mode} without a session: switched to {SAFE_MODE} before arming"
        self._link.action.arm()
        return note or "armed"

    def _disarm(self, cmd: Command) -> None:
        self._link.action.disarm(force=cmd.force)
        self._lifecycle.disarmed()

    def _takeoff(self, cmd: Command) -> None:
        if self._lifecycle.in_session:
            self._lifecycle.leave(SAFE_MODE, f"takeoff by {cmd.client_id}")
        self._link.action.takeoff(cmd.value or 5.0)

    def _goto(self, client: str, north: float, east: float, altitude: float) -> str:
        """PX4 worker: leave an offboard session for Hold, then DO_REPOSITION to the point's latitude and
        longitude, from where the drone is now in both frames (flat earth: a goto stays within the fence)."""
        here, there = self._link.telemetry.latest(LocalPosition), self._link.telemetry.latest(GlobalPosition)
        if here is None or there is None:
            raise CommandError(0, None, "goto: no position from PX4 yet (LOCAL_POSITION_NED, GLOBAL_POSITION_INT)")
        if self._lifecycle.in_session:
            self._failsafe.clear()
            self._lifecycle.leave(SAFE_MODE, f"goto by {client}")
        lat = there.lat_deg + math.degrees((north - here.x) / EARTH_RADIUS_M)
        lon = there.lon_deg + math.degrees((east - here.y) / (EARTH_RADIUS_M * math.cos(math.radians(there.lat_deg))))
        self._link.action.goto_location(lat, lon, there.alt_m - there.relative_alt_m + altitude)
        return f"going to N {north:.1f} E {east:.1f} at {altitude:.1f} m"

    def _hold_here(self) -> str:
        self._link.action.hold_here()
        return "holding where it is"

    def _set_param(self, cmd: Command) -> str | None:
        r = self._link.param.set(cmd.text, cmd.value)
        return r if isinstance(r, str) else None
