"""COMMAND_LONG with COMMAND_ACK: wait, retry on silence, map results to exceptions.

MAVLink's command protocol: the sender repeats a command (incrementing ``confirmation``)
until a COMMAND_ACK arrives; MAV_RESULT_IN_PROGRESS means "wait longer". PX4 answers a
refused mode change or arming with TEMPORARILY_REJECTED, an impossible request with
DENIED, a command nobody handles with UNSUPPORTED.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

MAV_RESULT_ACCEPTED = 0
MAV_CMD_DO_SET_MODE = 176
# PX4 answers every DO_SET_MODE twice, 0-8 ms apart (px4_traces: all 9 mode requests of the flight):
# the second ACK of one request must not answer the next request of the same command.
DOUBLE_ACKED = frozenset({MAV_CMD_DO_SET_MODE})
ECHO_WINDOW_S = 0.3
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4
MAV_RESULT_IN_PROGRESS = 5
MAV_RESULT_CANCELLED = 6

RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED",
                4: "FAILED", 5: "IN_PROGRESS", 6: "CANCELLED", 7: "COMMAND_LONG_ONLY",
                8: "COMMAND_INT_ONLY", 9: "COMMAND_UNSUPPORTED_MAV_FRAME"}

# The commands the link uses, for readable errors.
COMMAND_NAMES = {16: "NAV_WAYPOINT", 20: "NAV_RETURN_TO_LAUNCH", 21: "NAV_LAND",
                 22: "NAV_TAKEOFF", 176: "DO_SET_MODE", 185: "DO_FLIGHTTERMINATION",
                 400: "COMPONENT_ARM_DISARM", 511: "SET_MESSAGE_INTERVAL",
                 512: "REQUEST_MESSAGE", 520: "REQUEST_AUTOPILOT_CAPABILITIES"}


def command_name(command: int) -> str:
    return COMMAND_NAMES.get(command, f"MAV_CMD {command}")


class CommandError(RuntimeError):
    """A command did not succeed. ``result`` is the MAV_RESULT, None when there was none."""

    def __init__(self, command: int, result: int | None, message: str) -> None:
        super().__init__(message)
        self.command = command
        self.result = result


class CommandDenied(CommandError):
    """MAV_RESULT_DENIED: the vehicle will not do this (retrying will not help)."""


class CommandTemporarilyRejected(CommandError):
    """MAV_RESULT_TEMPORARILY_REJECTED: not now (e.g. OFFBOARD without a setpoint stream)."""


class CommandUnsupported(CommandError):
    """MAV_RESULT_UNSUPPORTED: the vehicle does not know this command."""


class CommandFailed(CommandError):
    """MAV_RESULT_FAILED / CANCELLED, or an accepted command whose effect never showed."""


class CommandTimeout(CommandError):
    """No COMMAND_ACK after all retries."""


class NotConnected(CommandError):
    """No vehicle heartbeat yet, so there is nobody to send the command to."""


class CommandCancelled(CommandError):
    """Withdrawn while waiting for its ACK (``CommandSender.cancel``): no more attempts are sent."""


_ERRORS: dict[int, type[CommandError]] = {
    MAV_RESULT_TEMPORARILY_REJECTED: CommandTemporarilyRejected,
    MAV_RESULT_DENIED: CommandDenied,
    MAV_RESULT_UNSUPPORTED: CommandUnsupported,
    MAV_RESULT_FAILED: CommandFailed,
    MAV_RESULT_CANCELLED: CommandFailed,
}


@dataclass(frozen=True, slots=True)
class CommandAck:
    command: int
    result: int
    attempts: int
    elapsed_s: float
    result_param2: int = 0


class CommandSender:
    """Runs one command at a time (MAVLink allows one in flight per command id; one overall
    keeps ACK matching trivial) and blocks the caller until the ACK or the last timeout.

    ``send`` is called with (command, params[7], confirmation); the link's receive thread
    calls ``handle_ack`` for every COMMAND_ACK from the vehicle.
    """

    def __init__(self, send: Callable[[int, Sequence[float], int], None],
                 timeout: float = 1.0, retries: int = 3,
                 context: Callable[[], str] | None = None,
                 double_acked: frozenset[int] = DOUBLE_ACKED) -> None:
        self._send = send
        self._double_acked = double_acked   # PX4's MAVLink ACKs these twice; its uORB ACK comes once
        self.timeout = timeout
        self.retries = retries
        self._context = context  # extra text for errors, e.g. the vehicle's last STATUSTEXT
        self._serial = threading.Lock()
        self._cond = threading.Condition()
        self._waiting_for: int | None = None
        self._ack: tuple[int, int, int] | None = None  # (result, progress, result_param2)
        self._answered = False
        self._owner: int | None = None     # thread ident of the command in flight
        self._cancelled = ""               # why the command in flight was withdrawn, or ""
        self.sent = 0
        self.retried = 0
        self.cancelled = 0
        self._echo: tuple[int, float] | None = None   # (command, until): its answer's second ACK to come
        self._second_seen = False                      # ... or already came while the answer was read
        self.echoes = 0

    @property
    def waiting_for(self) -> int | None:
        """The command whose ACK a caller waits for now, if any."""
        return self._waiting_for

    def cancel(self, owner: int, why: str) -> bool:
        """Withdraw the command in flight if thread ``owner`` sent it: its ``run`` raises
        CommandCancelled at once and sends no more attempts, so a more urgent command (a failsafe
        HOLD from another thread) gets the link now, not after the retries. Any thread; True if
        one was withdrawn. Only the named thread's command, so a failsafe is never withdrawn."""
        with self._cond:
            if self._waiting_for is None or self._owner != owner or self._answered:
                return False
            self._cancelled = why or "cancelled"
            self.cancelled += 1
            self._cond.notify_all()
            return True

    def handle_ack(self, command: int, result: int, progress: int = 0,
                   result_param2: int = 0) -> str:
        """Deliver an ACK; returns "used", "duplicate" or "unsolicited".

        The first ACK of an attempt wins: a later one (PX4 ACKs DO_SET_MODE twice, and a
        flood of forged ACKs would otherwise overwrite a refusal) never turns it around.
        """
        with self._cond:
            echo = self._echo
            if echo is not None and echo[0] == command:
                self._echo = None
                if time.monotonic() <= echo[1]:
                    self.echoes += 1
                    return "duplicate"
            if self._waiting_for != command:
                return "unsolicited"
            if self._ack is not None or self._answered:
                self._second_seen = True
                return "duplicate"
            self._ack = (result, progress, result_param2)
            self._answered = result != MAV_RESULT_IN_PROGRESS
            self._cond.notify_all()
            return "used"

    def run(self, command: int, params: Sequence[float] = (), *, timeout: float | None = None,
            retries: int | None = None) -> CommandAck:
        """Send and wait; return the ACK when ACCEPTED, raise a CommandError otherwise."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        if len(p) != 7:
            raise ValueError("a COMMAND_LONG has at most 7 params")
        timeout = self.timeout if timeout is None else timeout
        retries = self.retries if retries is None else retries
        name = command_name(command)
        start = time.monotonic()
        with self._serial:
            with self._cond:
                self._waiting_for = command
                self._ack = None
                self._answered = False
                self._owner = threading.get_ident()
                self._cancelled = ""
                self._second_seen = False
            try:
                attempts = 0
                while attempts <= retries:
                    self._send(command, p, attempts)  # confirmation = attempt number
                    self.sent += 1
                    if attempts:
                        self.retried += 1
                    attempts += 1
                    deadline = time.monotonic() + timeout
                    with self._cond:
                        while True:
                            if self._ack is not None:
                                result, _progress, param2 = self._ack
                                self._ack = None
                                if result == MAV_RESULT_IN_PROGRESS:
                                    # Keep listening without resending: the vehicle is on it.
                                    deadline = time.monotonic() + timeout
                                    continue
                                if command in self._double_acked and not self._second_seen:
                                    self._echo = (command, time.monotonic() + ECHO_WINDOW_S)
                                return self._finish(command, result, param2, attempts, start)
                            if self._cancelled:
                                raise CommandCancelled(command, None, f"{name}: {self._cancelled}")
                            left = deadline - time.monotonic()
                            if left <= 0:
                                break
                            self._cond.wait(left)
                raise CommandTimeout(command, None, f"{name}: no COMMAND_ACK after {attempts} "
                                                    f"attempt(s) of {timeout:g} s")
            finally:
                with self._cond:
                    self._waiting_for = None
                    self._owner = None

    def _finish(self, command: int, result: int, param2: int, attempts: int,
                start: float) -> CommandAck:
        if result == MAV_RESULT_ACCEPTED:
            return CommandAck(command, result, attempts, time.monotonic() - start, param2)
        err = _ERRORS.get(result, CommandFailed)
        msg = f"{command_name(command)}: {RESULT_NAMES.get(result, result)}"
        extra = self._context() if self._context else ""
        if extra:
            msg += f" ({extra})"
        raise err(command, result, msg)
