"""The companion's ``command`` service: who may command the drone, what is allowed, and who does it.

A command passes three gates, in order: it is one of the contract's (``drone_contract.commands``);
its sender holds control or claims it (the ControlArbiter; ``take_control`` and ``release_control``
are answered here, without PX4); the one policy (``command_policy``) allows it whoever sends it.
Then its handler, from the table keyed by ``CommandName``, runs on the PX4 worker and the reply
waits for it. Every command is logged with its sender and every refusal says why.

Threads: ``on_command`` runs on the node's executor (it blocks until the worker is done, up to
``TIMEOUT_S``); handlers run on the PX4 worker, one at a time.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable

from drone_contract.commands import COMMAND_SPECS, COMMANDS, CommandName, command_name
from drone_contract.messages import Command, CommandResult, valid_client_id
from px4_link import Px4Link
from px4_link.commands import CommandError
from px4_link.targets import TargetRefused

from .config import CompanionConfig
from .control import ControlArbiter
from .events import EventReporter
from .failsafe import DeadlineFailsafe
from .offboard_session import SAFE_MODE, OffboardLifecycle
from .px4_worker import Px4Worker
from .setpoint_gate import SetpointGate

log = logging.getLogger("companion")   # the app's logger: log lines keep the name they always had

Handler = Callable[[Command], str | None]   # runs on the PX4 worker; a str is the reply's message


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
    return ""


class CommandDesk:
    TIMEOUT_S = 20.0
    # Answered by the control claim itself, never by PX4.
    CONTROL_ONLY = (CommandName.TAKE_CONTROL, CommandName.RELEASE_CONTROL)

    def __init__(self, link: Px4Link, control: ControlArbiter, lifecycle: OffboardLifecycle,
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
        }
        unanswered = set(COMMAND_SPECS) - set(self._handlers) - set(self.CONTROL_ONLY)
        if unanswered:   # a command added to the contract must get a handler here
            raise RuntimeError(f"commands without a handler: {sorted(unanswered)}")

    def on_command(self, cmd: Command) -> CommandResult:
        who = cmd.client_id if valid_client_id(cmd.client_id) else f"<invalid {cmd.client_id[:64]!r}>"
        log.info("command %s (value=%g text=%r force=%s) from %s", cmd.name[:32], cmd.value, cmd.text[:32],
                 cmd.force, who)
        res = self._decide(cmd)
        if not res.success:
            log.warning("command %s from %s refused or failed: %s", cmd.name[:32], who, res.message)
        return res

    def _result(self, ok: bool, message: str) -> CommandResult:
        return CommandResult(ok, message, self._link.state.mode)

    def _refuse(self, why: str) -> CommandResult:
        self.refused += 1
        return self._result(False, why)

    def _decide(self, cmd: Command) -> CommandResult:
        name = command_name(cmd.name)
        if name is None:
            return self._refuse(f"unknown command {cmd.name[:32]!r}; commands: {', '.join(COMMANDS)}")
        client = cmd.client_id
        if name is CommandName.RELEASE_CONTROL:
            if self._control.release(client):
                self._events.event("control_changed", f"{client} released control", "no GCS in control", client)
                return self._result(True, "control released")
            return self._refuse(f"release_control refused: {client or '<none>'} does not hold control "
                                f"(holder: {self._control.holder or 'none'})")
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
        future = self._worker.submit(handler, cmd)
        try:
            msg = future.result(timeout=self.TIMEOUT_S)
        except (CommandError, TargetRefused) as exc:
            return self._result(False, str(exc))
        except Exception as exc:  # noqa: BLE001  (a bad argument, a link that is down: the sender hears it)
            return self._result(False, f"{type(exc).__name__}: {exc}")
        return self._result(True, msg if isinstance(msg, str) and msg else "done")

    # -- handlers (PX4 worker) -----------------------------------------------------------
    def _leave_for(self, mode: str) -> Handler:
        def leave(cmd: Command) -> None:
            self._failsafe.clear()
            self._lifecycle.leave(mode, f"{cmd.name} by {cmd.client_id}")
        return leave

    def _arm(self, cmd: Command) -> str:
        # Arming must never take off by itself: PX4 sitting in OFFBOARD outside a session
        # (it returns there after landing) goes to Hold first.
        note = ""
        if self._link.mode == "OFFBOARD" and not self._lifecycle.in_session:
            self._lifecycle.park("arm outside an offboard session")
            note = f"PX4 was in OFFBOARD without a session: switched to {SAFE_MODE} before arming"
        self._link.action.arm()
        return note or "armed"

    def _disarm(self, cmd: Command) -> None:
        self._link.action.disarm(force=cmd.force)
        self._lifecycle.disarmed()

    def _takeoff(self, cmd: Command) -> None:
        if self._lifecycle.in_session:
            self._lifecycle.leave(SAFE_MODE, f"takeoff by {cmd.client_id}")
        self._link.action.takeoff(cmd.value or 5.0)

    def _set_param(self, cmd: Command) -> str | None:
        r = self._link.param.set(cmd.text, cmd.value)
        return r if isinstance(r, str) else None
