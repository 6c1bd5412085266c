"""``ExternalMode``: one PX4 external mode, registered and kept alive over PX4's own zenoh module.

What PX4 expects of a mode (commander/ModeManagement.cpp, checks/externalChecks.cpp, PX4 main 2026-03), and
how this class meets it:
- **registration**: a RegisterExtComponentRequest with a random 64-bit request_id; PX4 answers on
  register_ext_component_reply, matched here by name AND request_id. A try without an answer is retried with
  a fresh request_id. PX4 does not de-duplicate: if a retry's request was only slow, PX4 registered the name
  twice, so every success reply after the one taken is unregistered at once (its first-reply-less slot would
  otherwise make PX4 read a zeroed reply, and it occupies a mode slot until PX4 drops it ~3.4 s later).
  PX4 refuses registrations while armed (unless COM_MODE_ARM_CHK): that refusal is raised, not retried.
- **heartbeat**: every arming_check_request (every ~300-310 ms) is answered at once, on Zenoh's thread,
  from ``check()`` -> (can_arm_and_run, reasons); each reason travels as an event (``messages.event_for``).
  PX4 counts a miss 50 ms after each request and flags the mode unresponsive on the 4th in a row: armed in
  the mode, PX4 falls back to RTL (a replacement falls back to PX4's own mode). ``check`` must be quick and
  must not block; an exception is a "not ready" answer naming it.
- **active** = ``vehicle_status.nav_state == mode_id`` and armed. Setpoints (trajectory_setpoint,
  goto_setpoint) and mode_completed are published only while active: PX4 flies whatever arrives on those
  uORB topics, so a setpoint outside the mode would fight PX4's own flight tasks.
- **unregistration** on ``close()`` (a context manager): PX4 then switches a selected mode to Hold.
- **executor** (``executor=True``, executor.py runs the sequence): registered with the mode in one request;
  ``in_charge`` from ``vehicle_status.executor_in_charge``; ``executor_command`` sends as component 1000+id on
  ``vehicle_command_mode_executor`` and takes PX4's ACK addressed to that component (3 sends of 300 ms, as
  px4-ros2); ``completions`` is PX4's ``mode_completed`` heard. Refused at construction on a bridge not
  declared fixed: there PX4 would run those commands without its in-charge check.
- **bridge bug**: nothing is ever sent on a topic this PX4's zenoh module misroutes (``bridge.py``), unless
  told the PX4 is fixed. Without it the mode keeps PX4's default control config (position, velocity,
  altitude, attitude, rates all enabled: what trajectory/goto setpoints need) and no config overrides.

Keys come from PX4's liveliness tokens (``topics.KeyBook``), never from our hashes alone.

Threading: Zenoh's callback threads answer checks and track vehicle_status under one lock; public methods may
be called from any thread; ``on_active`` runs on a Zenoh thread, outside the lock.
"""
from __future__ import annotations

import logging
import queue
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh

from px4_zenoh import topics as tp
from px4_zenoh.uorb import UorbCodec, load_types
from zenoh_robot.wire.ros2 import pack_attachment

from . import messages as m
from .bridge import BridgePolicy

log = logging.getLogger(__name__)

Check = Callable[[], tuple[bool, Sequence[str]]]
TYPES = ("RegisterExtComponentRequest", "RegisterExtComponentReply", "UnregisterExtComponent",
         "ArmingCheckRequest", "ArmingCheckReply", "Event", "ModeCompleted", "GotoSetpoint",
         "TrajectorySetpoint", "VehicleStatus", "VehicleCommand", "VehicleCommandAck", "ConfigOverrides")
TOPICS: tuple[tp.Px4Topic, ...] = tp.EXTERNAL_MODE_TOPICS + (tp.VEHICLE_STATUS, tp.VEHICLE_COMMAND, tp.COMMAND_ACK,
                                                             tp.TRAJECTORY, tp.CONFIG_OVERRIDES_REQUEST,
                                                             tp.COMMAND_MODE_EXECUTOR)
REGISTRATION_TOPICS = (tp.REGISTER_REQUEST, tp.REGISTER_REPLY, tp.UNREGISTER, tp.CHECK_REQUEST, tp.CHECK_REPLY,
                       tp.VEHICLE_STATUS)
# What this class publishes; declared before the first use (a fresh publisher may drop its first put while
# Zenoh still learns who subscribes), the registration's own waited on until PX4's subscriber matches.
SENT = (tp.REGISTER_REQUEST, tp.UNREGISTER, tp.CHECK_REPLY, tp.TRAJECTORY, tp.GOTO, tp.MODE_COMPLETED_IN,
        tp.VEHICLE_COMMAND)
MUST_MATCH = (tp.REGISTER_REQUEST, tp.UNREGISTER, tp.CHECK_REPLY)
GID = bytes.fromhex("7a72000000000000000000000000e0de")   # ours, for rmw_zenoh's attachment (PX4 ignores it)
SOURCE_SYSTEM, SOURCE_COMPONENT = 245, 191                 # as px4_zenoh.core's commands
UNREGISTER_SPACING_S = 0.06   # PX4's unregister queue holds one: give its 10 ms cycle time to take each
PERIODS_KEPT = 512
EXECUTOR_TRIES, EXECUTOR_ACK_S = 3, 0.3   # px4-ros2 ModeExecutorBase::sendCommandSync: 3 sends, 300 ms each
COMPLETIONS_KEPT = 64


def _matching(pub: zenoh.Publisher) -> bool:
    """Whether PX4's subscriber is known to this publisher (zenoh-python's stub says bool; 1.x returns a
    MatchingStatus with ``.matching``)."""
    status: Any = pub.matching_status
    return bool(getattr(status, "matching", status))


class RegistrationError(RuntimeError):
    """PX4 refused the registration, or never answered."""


@dataclass(frozen=True)
class Registration:
    request_id: int
    mode_id: int            # the nav_state PX4 gave the mode (23..30)
    arming_check_id: int
    took_s: float           # first request -> the reply taken
    tries: int
    mode_executor_id: int = -1   # the executor PX4 gave us (1..5), -1 without one


@dataclass
class ModeStats:
    check_requests: int = 0
    replies_sent: int = 0
    request_times: deque[float] = field(default_factory=lambda: deque(maxlen=PERIODS_KEPT))
    setpoints_sent: int = 0
    setpoints_withheld: int = 0         # asked while not active: not sent
    extras_unregistered: int = 0
    check_errors: int = 0
    registrations_lost: int = 0         # PX4 stopped listing the mode (a reboot, or it dropped us)

    def periods(self) -> list[float]:
        t = list(self.request_times)
        return [b - a for a, b in zip(t, t[1:], strict=False)]


class ExternalMode:
    """A named PX4 mode run by this process; see the module docstring for the protocol."""

    def __init__(self, session: zenoh.Session, name: str, check: Check, *, domain: int = 0,
                 replace_internal_mode: str | int | None = None, requires_position: bool = True,
                 bridge: BridgePolicy | None = None, msg_dir: Path | None = None,
                 on_active: Callable[[bool], None] | None = None, executor: bool = False) -> None:
        m.encode_name(name)   # refuse a name PX4 would cut
        self.bridge = bridge or BridgePolicy.from_env()
        if executor:
            # An executor's commands are only safe if PX4 checks that the executor is in charge; this PX4's
            # bridge hands them to vehicle_command unchecked (bridge.py): refused before anything is sent.
            self.bridge.require(tp.COMMAND_MODE_EXECUTOR)
        self.executor = executor
        self.name = name
        self.check = check
        self.domain = domain
        self.replaces = m.internal_mode(replace_internal_mode)
        self.requires_position = requires_position
        self.on_active = on_active
        self._session = session
        self._types: dict[str, Any] = dict(load_types(msg_dir, TYPES))
        self._codecs = {n: UorbCodec.of(c) for n, c in self._types.items()}
        self.keys = tp.KeyBook(domain, {c.type_name: c.type_hash for c in self._codecs.values()}, TOPICS)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._reg: Registration | None = None
        self._sent: dict[int, float] = {}          # request_id -> time sent (our tries)
        self._replies: list[Any] = []              # replies to our request_ids, in arrival order
        self._nav_state = -1
        self._armed = False
        self._in_charge = 0                        # vehicle_status.executor_in_charge
        self._failsafe = False
        self._completed: deque[tuple[float, int, int]] = deque(maxlen=COMPLETIONS_KEPT)   # (time, nav, result)
        self._exec_acks: list[Any] = []
        self._sysid = 1
        self._active = False
        self._unlisted = 0                         # vehicle_status samples in a row without our mode
        self._acks: list[Any] = []
        self._verdict: tuple[bool, tuple[str, ...]] = (False, ("not registered",))
        self._seq: dict[str, int] = {}
        self._pubs: dict[str, zenoh.Publisher] = {}
        self.stats = ModeStats()
        self._extras: queue.Queue[tuple[int, int, int] | None] = queue.Queue()
        self._janitor = threading.Thread(target=self._unregister_extras, name=f"px4mode-{name}", daemon=True)
        self._janitor.start()
        self._entities: list[Any] = []
        lv = session.liveliness()
        for pattern in sorted({tp.token_pattern(domain), tp.token_pattern(0)}):
            self._entities.append(lv.declare_subscriber(pattern, self._on_token, history=True))
        for topic, handler in ((tp.REGISTER_REPLY, self._on_register_reply),
                               (tp.CHECK_REQUEST, self._on_check_request),
                               (tp.VEHICLE_STATUS, self._on_status), (tp.COMMAND_ACK, self._on_ack),
                               (tp.MODE_COMPLETED_OUT, self._on_completed)):
            self._entities.append(session.declare_subscriber(topic.any_hash_key(domain),
                                                             self._receiver(topic, handler)))

    # ---------------------------------------------------------------- state
    @property
    def registration(self) -> Registration | None:
        with self._lock:
            return self._reg

    @property
    def mode_id(self) -> int:
        with self._lock:
            return self._reg.mode_id if self._reg is not None else -1

    @property
    def active(self) -> bool:
        """PX4 flies this mode now: nav_state is ours and the vehicle is armed."""
        with self._lock:
            return self._active

    @property
    def selected(self) -> bool:
        with self._lock:
            return self._reg is not None and self._nav_state == self._reg.mode_id

    @property
    def armed(self) -> bool:
        with self._lock:
            return self._armed

    @property
    def nav_state(self) -> int:
        """PX4's nav_state as last heard (-1 before vehicle_status)."""
        with self._lock:
            return self._nav_state

    @property
    def in_charge(self) -> bool:
        """Our executor is in charge (vehicle_status.executor_in_charge; PX4 puts it back to 0 in a failsafe)."""
        with self._lock:
            return self._reg is not None and self._reg.mode_executor_id > 0 and \
                self._in_charge == self._reg.mode_executor_id

    @property
    def failsafe(self) -> bool:
        with self._lock:
            return self._failsafe

    def completions(self, since: float = 0.0) -> list[tuple[float, int, int]]:
        """PX4's mode_completed heard since ``since`` (monotonic): (time, nav_state, result)."""
        with self._lock:
            return [c for c in self._completed if c[0] >= since]

    @property
    def verdict(self) -> tuple[bool, tuple[str, ...]]:
        """The last answer given to PX4's check."""
        with self._lock:
            return self._verdict

    # ---------------------------------------------------------------- registration
    def register(self, tries: int = 5, try_timeout_s: float = 1.0, keys_timeout_s: float = 10.0) -> Registration:
        """Register the mode (blocking; the registration in force if there is one); RegistrationError when
        PX4 refuses or stays silent."""
        current = self.registration
        if current is not None:
            return current
        self._wait_keys(keys_timeout_s)
        self._declare_publishers(keys_timeout_s)
        t0 = time.monotonic()
        for attempt in range(1, tries + 1):
            rid = secrets.randbits(64)
            with self._lock:
                self._sent[rid] = time.monotonic()
            self._put(tp.REGISTER_REQUEST, m.register_request(self._types, self.name, rid, self.replaces,
                                                              self.executor))
            with self._cond:
                self._cond.wait_for(lambda: bool(self._replies), try_timeout_s)
                taken = next((r for r in self._replies if r.success), None)
                if taken is not None:
                    self._reg = Registration(int(taken.request_id), int(taken.mode_id), int(taken.arming_check_id),
                                             time.monotonic() - t0, attempt, int(taken.mode_executor_id))
                    extras = [r for r in self._replies if r.success and r is not taken]
                    self._replies.clear()
                    reg = self._reg
                elif self._replies:
                    refused = self._replies[0]
                    self._replies.clear()
                    raise RegistrationError(self._refusal(refused))
                else:
                    continue
            for r in extras:
                self._extras.put((int(r.arming_check_id), int(r.mode_id), int(r.mode_executor_id)))
            log.info("px4 mode %r: registered as nav_state %d (check %d) in %.3f s, %d tries", self.name,
                     reg.mode_id, reg.arming_check_id, reg.took_s, attempt)
            return reg
        raise RegistrationError(f"PX4 did not answer {tries} registration requests for {self.name!r}")

    def _refusal(self, reply: Any) -> str:
        why = ("PX4 refuses registrations while armed (COM_MODE_ARM_CHK=0)" if self._armed else
               "no free mode slot, or the internal mode is already replaced")
        return f"PX4 refused mode {self.name!r}: {why}"

    def _wait_keys(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            missing = [t.name for t in REGISTRATION_TOPICS if self.keys.key(t) is None]
            if not missing:
                return
            if time.monotonic() > deadline:
                bad = "; ".join(str(mm) for mm in self.keys.mismatches())
                raise RegistrationError(f"PX4 announces no usable {', '.join(missing)}" + (f" ({bad})" if bad else ""))
            time.sleep(0.02)

    def _declare_publishers(self, timeout_s: float) -> None:
        for topic in SENT + ((tp.COMMAND_MODE_EXECUTOR,) if self.executor else ()):
            self._publisher(topic)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            pubs = [self._publisher(t) for t in MUST_MATCH]
            if all(p is not None and _matching(p) for p in pubs):
                return
            time.sleep(0.01)
        log.warning("px4 mode %r: PX4's subscribers not matched yet; sending anyway", self.name)

    def unregister(self) -> None:
        with self._lock:
            reg, self._reg = self._reg, None
            self._active = False
        if reg is not None:
            self._put(tp.UNREGISTER, m.unregister(self._types, self.name, reg.arming_check_id, reg.mode_id,
                                                  reg.mode_executor_id))

    def _unregister_extras(self) -> None:
        while True:
            item = self._extras.get()
            if item is None:
                return
            check_id, mode_id, executor_id = item
            log.warning("px4 mode %r: PX4 registered a retry too (nav_state %d); unregistering it", self.name, mode_id)
            self._put(tp.UNREGISTER, m.unregister(self._types, self.name, check_id, mode_id, executor_id))
            with self._lock:
                self.stats.extras_unregistered += 1
            time.sleep(UNREGISTER_SPACING_S)

    # ---------------------------------------------------------------- what the mode sends
    def trajectory(self, position: Sequence[float] | None = None, velocity: Sequence[float] | None = None,
                   yaw: float | None = None) -> bool:
        """A trajectory_setpoint (NED m, m/s, rad); sent only while active. True if sent."""
        return self._send_setpoint(tp.TRAJECTORY, m.trajectory(self._types, position, velocity, yaw))

    def goto(self, position: Sequence[float], heading: float | None = None) -> bool:
        """A goto_setpoint (PX4 flies it for 500 ms: repeat it); sent only while active."""
        return self._send_setpoint(tp.GOTO, m.goto(self._types, position, heading))

    def _send_setpoint(self, topic: tp.Px4Topic, msg: Any) -> bool:
        with self._lock:
            if not self._active:
                self.stats.setpoints_withheld += 1
                return False
            self.stats.setpoints_sent += 1
        self._put(topic, msg)
        return True

    def complete(self, success: bool = True) -> bool:
        """Report the mode's end (mode_completed), as a px4-ros2 mode does; only while active."""
        with self._lock:
            if not self._active or self._reg is None:
                return False
            nav = self._reg.mode_id
        self._put(tp.MODE_COMPLETED_IN, m.mode_completed(self._types, nav, success))
        return True

    def select(self, timeout_s: float = 3.0) -> int:
        """Ask PX4 to switch to this mode (VEHICLE_CMD_SET_NAV_STATE); PX4's ACK result (0: accepted)."""
        with self._lock:
            if self._reg is None:
                raise RegistrationError(f"mode {self.name!r} is not registered")
            nav, sysid = self._reg.mode_id, self._sysid
            self._acks.clear()
        self._put(tp.VEHICLE_COMMAND, m.set_nav_state(self._types, nav, sysid, SOURCE_SYSTEM, SOURCE_COMPONENT))
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._acks), timeout_s):
                raise TimeoutError(f"PX4 did not acknowledge the switch to {self.name!r}")
            return int(self._acks[0].result)

    def request_overrides(self, defer_failsafes: bool = False, defer_timeout_s: int = 0,
                          disable_auto_disarm: bool = False) -> None:
        """config_overrides_request: only to a PX4 whose bridge delivers it (BridgeBugError otherwise)."""
        self.bridge.require(tp.CONFIG_OVERRIDES_REQUEST)
        nav = self.mode_id
        if nav < 0:
            raise RegistrationError(f"mode {self.name!r} is not registered")
        self._put(tp.CONFIG_OVERRIDES_REQUEST, m.overrides(self._types, nav, defer_failsafes, defer_timeout_s,
                                                           disable_auto_disarm))

    # ---------------------------------------------------------------- Zenoh's threads
    def _receiver(self, topic: tp.Px4Topic, handler: Callable[[Any], None]) -> Callable[[zenoh.Sample], None]:
        codec = self._codecs[topic.type_short]

        def on_sample(sample: zenoh.Sample) -> None:
            if str(sample.key_expr) != self.keys.key(topic):   # not PX4's announced key
                return
            try:
                msg = codec.decode(sample.payload.to_bytes())
            except ValueError as e:
                log.debug("px4 mode %r: %s: %s", self.name, topic.name, e)
                return
            handler(msg)
        return on_sample

    def _on_token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            mm = self.keys.learn(str(sample.key_expr))
            if mm is not None:
                log.warning("px4 mode %r: %s", self.name, mm)

    def _on_register_reply(self, reply: Any) -> None:
        if m.decode_name(reply.name) != self.name:
            return
        rid = int(reply.request_id)
        with self._cond:
            if rid not in self._sent:
                return
            taken = self._reg is not None and self._reg.request_id == rid
            if taken:
                return
            if self._reg is not None:        # a late answer to a retry: PX4 registered us twice
                if reply.success:
                    self._extras.put((int(reply.arming_check_id), int(reply.mode_id), int(reply.mode_executor_id)))
                return
            self._replies.append(reply)
            self._cond.notify_all()

    def _on_check_request(self, req: Any) -> None:
        with self._lock:
            reg = self._reg
            if reg is None:
                return
            self.stats.check_requests += 1
            self.stats.request_times.append(time.monotonic())
        try:
            can, reasons = self.check()
            verdict = (bool(can), tuple(str(r) for r in reasons))
        except Exception as e:   # noqa: BLE001 - a failing check is a "not ready" answer, never silence
            verdict = (False, (f"check raised {type(e).__name__}",))
            with self._lock:
                self.stats.check_errors += 1
        if not verdict[0] and not verdict[1]:
            verdict = (False, ("not ready",))
        self._put(tp.CHECK_REPLY, m.check_reply(self._types, int(req.request_id), reg.arming_check_id, verdict[0],
                                                verdict[1], self.requires_position))
        with self._lock:
            self._verdict = verdict
            self.stats.replies_sent += 1

    def _on_status(self, st: Any) -> None:
        with self._lock:
            self._nav_state = int(st.nav_state)
            self._armed = int(st.arming_state) == m.ARMING_STATE_ARMED
            self._in_charge, self._failsafe = int(st.executor_in_charge), bool(st.failsafe)
            self._sysid = int(st.system_id) or 1
            self._check_listed(int(st.can_set_nav_states_mask))
            active = self._reg is not None and self._nav_state == self._reg.mode_id and self._armed
            changed, self._active = active != self._active, active
            self._cond.notify_all()   # wait() re-checks on every status
        if changed and self.on_active is not None:
            self.on_active(active)

    def _check_listed(self, can_set_mask: int) -> None:
        """PX4 lists every registered mode as settable (ModeManagement::getModeStatus); two statuses in a row
        without ours (one may predate the registration) mean PX4 no longer has it: a reboot, or PX4 removed
        it as unresponsive. The registration is dropped, so ``keep_registered`` registers again."""
        if self._reg is None or can_set_mask >> self._reg.mode_id & 1:
            self._unlisted = 0
            return
        self._unlisted += 1
        if self._unlisted >= 2:
            log.warning("px4 mode %r: PX4 no longer lists nav_state %d; registration lost", self.name,
                        self._reg.mode_id)
            self._reg, self._unlisted = None, 0
            self.stats.registrations_lost += 1

    def keep_registered(self, stop: threading.Event, retry_s: float = 2.0) -> None:
        """Register, and register again whenever the registration is lost, until ``stop`` (a thread's loop)."""
        while not stop.is_set():
            if self.registration is None:
                try:
                    self.register(tries=3, try_timeout_s=1.0, keys_timeout_s=retry_s)
                except RegistrationError as e:
                    log.warning("px4 mode %r: %s; trying again in %g s", self.name, e, retry_s)
                    stop.wait(retry_s)
                    continue
            stop.wait(0.2)

    def _on_ack(self, ack: Any) -> None:
        with self._cond:
            reg = self._reg
            if reg is not None and reg.mode_executor_id > 0 and \
                    int(ack.target_component) == m.COMPONENT_MODE_EXECUTOR_START + reg.mode_executor_id:
                self._exec_acks.append(ack)     # an answer to our executor (as px4-ros2 matches it)
                self._cond.notify_all()
                return
            if int(ack.command) != m.CMD_SET_NAV_STATE or int(ack.target_system) != SOURCE_SYSTEM:
                return
            self._acks.append(ack)
            self._cond.notify_all()

    def _on_completed(self, done: Any) -> None:
        with self._cond:
            self._completed.append((time.monotonic(), int(done.nav_state), int(done.result)))
            self._cond.notify_all()

    def executor_command(self, command: int, *params: float) -> int | None:
        """Send a command as our mode executor (vehicle_command_mode_executor, source_component 1000+id); PX4's
        ACK result, or None when none came (3 sends, 300 ms each, as px4-ros2's sendCommandSync). PX4 runs it
        only while the executor is in charge (TEMPORARILY_REJECTED otherwise). Needs a fixed bridge."""
        self.bridge.require(tp.COMMAND_MODE_EXECUTOR)
        with self._lock:
            reg = self._reg
            if reg is None or reg.mode_executor_id < 0:
                raise RegistrationError(f"mode {self.name!r} has no registered executor")
            sysid = self._sysid
        msg = m.executor_command(self._types, command, params, sysid, reg.mode_executor_id)
        for _ in range(EXECUTOR_TRIES):
            with self._lock:
                self._exec_acks.clear()
            self._put(tp.COMMAND_MODE_EXECUTOR, msg)
            with self._cond:
                if self._cond.wait_for(lambda: any(int(a.command) == command for a in self._exec_acks),
                                       EXECUTOR_ACK_S):
                    return int(next(a for a in self._exec_acks if int(a.command) == command).result)
        return None

    def wait(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Block until ``predicate`` (called under no lock) holds, re-checked on every PX4 message this class
        hears; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            with self._cond:
                self._cond.wait(min(left, 0.05))
        return True

    # ---------------------------------------------------------------- sending
    def _put(self, topic: tp.Px4Topic, msg: Any) -> None:
        self.bridge.require(topic)   # never a misrouted topic, whatever the caller did
        pub = self._publisher(topic)
        if pub is None:
            log.warning("px4 mode %r: PX4 announces no %s; not sent", self.name, topic.name)
            return
        with self._lock:
            seq = self._seq[topic.name] = self._seq.get(topic.name, 0) + 1
        pub.put(self._codecs[topic.type_short].encode(msg), attachment=pack_attachment(seq, time.time_ns(), GID))

    def _publisher(self, topic: tp.Px4Topic) -> zenoh.Publisher | None:
        key = self.keys.key(topic)
        if key is None:
            return None
        with self._lock:
            pub = self._pubs.get(key)
            if pub is None:
                pub = self._pubs[key] = self._session.declare_publisher(key)
            return pub

    # ---------------------------------------------------------------- lifecycle
    def close(self) -> None:
        """Unregister (PX4 switches a selected mode to Hold) and release the Zenoh entities."""
        try:
            self.unregister()
        except zenoh.ZError as e:   # the session is already gone: PX4 will find the mode unresponsive
            log.debug("px4 mode %r: unregister on a closed session: %s", self.name, e)
        self._extras.put(None)
        self._janitor.join(2.0)
        for entity in self._entities + list(self._pubs.values()):
            try:
                entity.undeclare()
            except Exception:   # noqa: BLE001 - the session may already be closed
                pass
        self._entities, self._pubs = [], {}

    def __enter__(self) -> ExternalMode:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
