"""PX4's external-mode management, as PX4 main of 2026-03 (02e73e3b) runs it in its commander.

One job: the bookkeeping PX4 keeps for components that register from outside (px4-ros2 modes, this
project's ``px4_zenoh.external_mode``): registrations, their 300 ms arming-check heartbeat and its miss
counting, the modes' slots and replacement of internal modes, executors and which one is in charge,
and what that means for "can this mode run / can we arm". No Zenoh, no uORB codec: the simulator
(``simulator.py``) feeds decoded messages in and publishes what comes out; ``ext_commander.py`` asks
it whether a mode can run.

Every rule cites the PX4 file and function it follows (read, not copied):
- ``ExternalChecks`` <- commander/HealthAndArmingChecks/checks/externalChecks.{hpp,cpp}:
  ``addRegistration``, ``removeRegistration``, ``isUnresponsive``, ``update`` (requests every
  UPDATE_INTERVAL, replies accepted for the current request_id only, a miss counted once per request
  REQUEST_TIMEOUT after it, unresponsive on the 4th consecutive miss, the 11th while waiting for the
  first reply; a registration without a mode is removed instead), ``checkAndReport`` (what a reply's
  can_arm_and_run / requirements / events do to the failsafe flags and arming bits),
  ``checkNonRegisteredModes``.
- ``ModeManagement`` <- commander/ModeManagement.{hpp,cpp}: ``Modes::addExternalMode`` (slot by the
  name's FNV-1a hash kept in COM_MODEn_HASH, so a name gets the same nav_state again),
  ``checkNewRegistrations`` (validation, free slots, one replacement per internal mode, reply),
  ``checkUnregistrations`` (selected -> Hold), ``update`` (registrations refused while armed unless
  COM_MODE_ARM_CHK; unresponsive unselected modes removed), ``onUserIntendedNavStateChange``,
  ``getNavStateReplacementIfValid``, ``getReplacedModeIfAny``, ``onDisarm``, ``modeExecutorInCharge``,
  ``getNavStateDisplay``, ``getModeStatus``.
- uORB queue lengths (msg/versioned/*.msg ORB_QUEUE_LENGTH): register request 2, arming_check_reply 4,
  unregister 1; a burst longer than that between two commander cycles loses the oldest, as in PX4.

Times are ``time.monotonic()`` seconds. PX4 runs this in its 10 ms commander cycle; the simulator
calls ``update`` on its 4 ms tick, so its check period is 300-304 ms where PX4's is 300-310 ms.

Threading: not thread-safe; the simulator calls it on its loop thread under its lock.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

FIRST_EXTERNAL_NAV_STATE = 23        # VehicleStatus NAVIGATION_STATE_EXTERNAL1
LAST_EXTERNAL_NAV_STATE = 30         # NAVIGATION_STATE_EXTERNAL8
MAX_MODES = LAST_EXTERNAL_NAV_STATE - FIRST_EXTERNAL_NAV_STATE + 1
MAX_REGISTRATIONS = 8                # ExternalChecks::MAX_NUM_REGISTRATIONS
MAX_EXECUTORS = 5                    # ModeExecutors::MAX_NUM
AUTOPILOT_EXECUTOR_ID = 0
FIRST_EXECUTOR_ID = 1
REQUEST_TIMEOUT_US = 50_000          # ExternalChecks::REQUEST_TIMEOUT (PX4 compares integer µs: so do we)
UPDATE_INTERVAL_US = 300_000         # ExternalChecks::UPDATE_INTERVAL
NUM_NO_REPLY_UNTIL_UNRESPONSIVE = 3
NUM_NO_REPLY_UNTIL_UNRESPONSIVE_INIT = 10
REPLACES_NONE = 0xFF
NAV_AUTO_LOITER = 4
API_VERSION = 1                      # RegisterExtComponentRequest LATEST_PX4_ROS2_API_VERSION
REQUEST_QUEUE, REPLY_QUEUE, UNREGISTER_QUEUE = 2, 4, 1
NAME_LEN = 25                        # char[25], the last one forced to NUL


def fnv1a_32(text: str) -> int:
    """events::util::hash_32_fnv1a_const, as an int32 (PX4 stores it in the COM_MODEn_HASH int32 param)."""
    h = 0x811C9DC5
    for b in text.encode():
        h = ((h ^ b) * 0x01000193) & 0xFFFFFFFF
    return h - (1 << 32) if h >= 1 << 31 else h


def is_external(nav_state: int) -> bool:
    return FIRST_EXTERNAL_NAV_STATE <= nav_state <= LAST_EXTERNAL_NAV_STATE


def name_of(raw: bytes | str) -> str:
    """A uORB char[25] as PX4 reads it: NUL-terminated, the last byte forced to NUL."""
    data = raw.encode() if isinstance(raw, str) else bytes(raw)
    data = data[:NAME_LEN - 1]
    return data.split(b"\0", 1)[0].decode("utf-8", "replace")


@dataclass
class CheckReply:
    """What PX4 keeps of an ArmingCheckReply (the fields checkAndReport reads)."""
    request_id: int = 0
    registration_id: int = 0
    can_arm_and_run: bool = False
    requires_position: bool = False      # mode_req_local_position / global_position (+ relaxed)
    prevent_arming: bool = False         # mode_req_prevent_arming
    events: list[tuple[int, bytes]] = field(default_factory=list)   # (event id, arguments)

    @classmethod
    def of(cls, msg: Any) -> CheckReply:
        n = min(int(msg.num_events), len(msg.events))
        return cls(int(msg.request_id), int(msg.registration_id), bool(msg.can_arm_and_run),
                   bool(msg.mode_req_local_position or msg.mode_req_local_position_relaxed
                        or msg.mode_req_global_position or msg.mode_req_global_position_relaxed),
                   bool(msg.mode_req_prevent_arming),
                   [(int(e.id), bytes(e.arguments)) for e in msg.events[:n]])


@dataclass
class Registration:
    """externalChecks.hpp Registration; slots keep their last reply when reused, as PX4's do."""
    nav_mode_id: int = -1
    replaces_nav_state: int = -1
    waiting_for_first_response: bool = True
    num_no_response: int = 0
    unresponsive: bool = False
    total_num_unresponsive: int = 0
    reply: CheckReply | None = None


@dataclass(frozen=True)
class CheckRequest:
    request_id: int
    valid_registrations_mask: int


@dataclass(frozen=True)
class RegisterReply:
    request_id: int
    name: str
    success: bool
    arming_check_id: int
    mode_id: int
    mode_executor_id: int
    not_user_selectable: bool


@dataclass
class Report:
    """One checkAndReport: what the external checks did to the failsafe flags and arming bits."""
    cannot_run: dict[int, str] = field(default_factory=dict)        # nav_state -> why (mode_req_other)
    cannot_arm: dict[int, str] = field(default_factory=dict)        # nav_state -> why (arming bits cleared)
    cannot_arm_any: str | None = None                               # a mode-less check refuses arming
    requires_position: set[int] = field(default_factory=set)
    events: list[tuple[int, int, bytes]] = field(default_factory=list)   # (registration, id, arguments)


class ExternalChecks:
    """The arming-check registrations and their heartbeat."""

    def __init__(self) -> None:
        self.slots = [Registration() for _ in range(MAX_REGISTRATIONS)]
        self.active_mask = 0
        self._last_update: int | None = None   # µs
        self._reply_received_mask = 0
        self._had_timeout = False
        self._current_request_id = 0
        self.replies: deque[CheckReply] = deque(maxlen=REPLY_QUEUE)
        self.log: list[tuple[float, str]] = []
        self.now = 0.0

    def valid(self, idx: int) -> bool:
        return 0 <= idx < MAX_REGISTRATIONS and bool(self.active_mask & (1 << idx))

    def has_free(self) -> bool:
        return self.active_mask != (1 << MAX_REGISTRATIONS) - 1

    def add(self, nav_mode_id: int, replaces_nav_state: int) -> int:
        for i in range(MAX_REGISTRATIONS):
            if not self.valid(i):
                self.active_mask |= 1 << i
                s = self.slots[i]
                s.nav_mode_id, s.replaces_nav_state = nav_mode_id, replaces_nav_state
                s.waiting_for_first_response, s.num_no_response = True, 0
                s.unresponsive, s.total_num_unresponsive = False, 0
                if s.reply is None:          # a reused slot keeps its old reply (PX4 allocates it once)
                    s.reply = CheckReply()
                return i
        return -1

    def remove(self, idx: int, nav_mode_id: int) -> bool:
        if self.valid(idx) and self.slots[idx].nav_mode_id == nav_mode_id:
            self.active_mask &= ~(1 << idx)
            return True
        self.log.append((self.now, "trying to remove inactive external check"))
        return False

    def is_unresponsive(self, idx: int) -> bool:
        return self.valid(idx) and self.slots[idx].unresponsive

    def update(self, now: float) -> CheckRequest | None:
        """externalChecks.cpp ExternalChecks::update: take the replies, count misses, maybe a new request."""
        self.now = now
        if self.active_mask == 0:
            return None
        now_us = round(now * 1e6)
        while self.replies:
            r = self.replies.popleft()
            # the bridge sets timestamp to PX4's receive time, so PX4's "timed_out" test never fires
            if self.valid(r.registration_id) and r.request_id == self._current_request_id:
                self._reply_received_mask |= 1 << r.registration_id
                s = self.slots[r.registration_id]
                s.num_no_response, s.waiting_for_first_response = 0, False
                if s.total_num_unresponsive <= 3:   # PX4: no toggling back after 3 episodes
                    s.unresponsive = False
                s.reply = r
        if self._last_update is not None and self._reply_received_mask != self.active_mask \
                and now_us > self._last_update + REQUEST_TIMEOUT_US and not self._had_timeout:
            self._had_timeout = True
            self._count_misses(self.active_mask & ~self._reply_received_mask)
        if self._last_update is None or now_us > self._last_update + UPDATE_INTERVAL_US:
            self._reply_received_mask = 0
            self._last_update = now_us
            self._had_timeout = False
            self._current_request_id = (self._current_request_id + 1) & 0xFF
            mask = self.active_mask
            for i, s in enumerate(self.slots):
                if s.unresponsive:
                    mask &= ~(1 << i)
            return CheckRequest(self._current_request_id, mask)
        return None

    def _count_misses(self, no_reply: int) -> None:
        for i, s in enumerate(self.slots):
            if not no_reply & (1 << i):
                continue
            limit = NUM_NO_REPLY_UNTIL_UNRESPONSIVE_INIT if s.waiting_for_first_response \
                else NUM_NO_REPLY_UNTIL_UNRESPONSIVE
            if s.unresponsive:
                continue
            s.num_no_response += 1
            if s.num_no_response > limit:
                if s.nav_mode_id == -1:      # not a mode: cleared at once
                    self.remove(i, -1)
                    self.log.append((self.now, f"No response from {i}, removing"))
                else:
                    s.unresponsive = True
                    s.total_num_unresponsive = min(100, s.total_num_unresponsive + 1)
                    self.log.append((self.now, f"No response from {i}, flagging unresponsive"))

    def check_and_report(self, report: Report) -> None:
        """externalChecks.cpp checkAndReport (+ checkNonRegisteredModes; PX4 also emits an event when the
        selected mode is the unregistered one, which nothing here reads)."""
        registered = {s.nav_mode_id for i, s in enumerate(self.slots) if self.valid(i)}
        for ns in range(FIRST_EXTERNAL_NAV_STATE, LAST_EXTERNAL_NAV_STATE + 1):
            if ns not in registered:
                report.cannot_arm[ns] = "Mode is not registered"
                report.cannot_run[ns] = "Mode is not registered"
        for idx, slot in enumerate(self.slots):
            if not self.valid(idx) or slot.reply is None:
                continue
            reply = slot.reply
            # PX4 reads the registration through the stored reply's registration_id (0 before a first reply)
            reg = self.slots[reply.registration_id] if reply.registration_id < MAX_REGISTRATIONS else slot
            nav = reg.nav_mode_id
            if reg.unresponsive:
                if nav != -1:
                    report.cannot_run[nav] = report.cannot_arm[nav] = "Mode is unresponsive"
                continue
            modes = [nav] if nav != -1 else []
            if nav != -1 and reg.replaces_nav_state != -1:
                modes.append(reg.replaces_nav_state)
            why = _reason(reply)
            if not reply.can_arm_and_run:
                if nav == -1:
                    report.cannot_arm_any = why
                for m in modes:
                    report.cannot_run[m] = report.cannot_arm[m] = why
            if nav != -1:
                for m in modes:
                    if reply.requires_position:
                        report.requires_position.add(m)
                    if reply.prevent_arming:
                        report.cannot_arm.setdefault(m, "Mode prevents arming")
            report.events += [(idx, eid, args) for eid, args in reply.events]


def _reason(reply: CheckReply) -> str:
    """The refusal text: the events' texts if the component put them there (this project's convention,
    ``external_mode.messages.event_for``), joined; else PX4's generic wording."""
    texts = [args[4:].split(b"\0", 1)[0].decode("utf-8", "replace") for _eid, args in reply.events]
    return "; ".join(t for t in texts if t) or "Mode not ready (external check)"


@dataclass
class ExtMode:
    """ModeManagement.hpp Modes::Mode."""
    name: str
    replaces_nav_state: int = REPLACES_NONE
    unresponsive_reported: bool = False
    arming_check_registration_id: int = -1
    mode_executor_registration_id: int = -1


@dataclass
class UpdateRequest:
    change_user_intended_nav_state: bool = False
    user_intended_nav_state: int = 0


class ModeManagement:
    """ModeManagement + Modes + ModeExecutors."""

    def __init__(self, allow_update_while_armed: bool = False, mode_hashes: list[int] | None = None) -> None:
        self.checks = ExternalChecks()
        self.allow_update_while_armed = allow_update_while_armed     # COM_MODE_ARM_CHK
        self.hashes = list(mode_hashes or [0] * MAX_MODES)           # COM_MODE0_HASH .. COM_MODE7_HASH
        self.modes: dict[int, ExtMode] = {}                          # nav_state -> mode
        self.executors: dict[int, int] = {}                          # executor id -> owned nav_state
        self._in_charge = AUTOPILOT_EXECUTOR_ID
        self.failsafe_action_active = False
        self.requests: deque[Any] = deque(maxlen=REQUEST_QUEUE)
        self.unregisters: deque[Any] = deque(maxlen=UNREGISTER_QUEUE)
        self.replies_out: list[RegisterReply] = []
        self.requests_out: list[CheckRequest] = []
        self.report = Report()
        self.log: list[tuple[float, str]] = []

    # ------------------------------------------------------------ slots
    def valid(self, nav_state: int) -> bool:
        return nav_state in self.modes

    def _add_mode(self, mode: ExtMode) -> int:
        """Modes::addExternalMode: the slot whose stored hash matches the name, else a free one."""
        h = fnv1a_32(mode.name) or 1
        first_unused = first_invalid = matching = -1
        for i in range(MAX_MODES):
            used = FIRST_EXTERNAL_NAV_STATE + i in self.modes
            if not used and self.hashes[i] == 0 and first_unused == -1:
                first_unused = i
            if self.hashes[i] == h:
                matching = i
            if not used and first_invalid == -1:
                first_invalid = i
        update_param, idx = False, -1
        if matching != -1:
            if FIRST_EXTERNAL_NAV_STATE + matching in self.modes:   # the name is registered twice
                self.log.append((self.checks.now, f"Mode '{mode.name}' already registered"))
                if first_unused != -1:
                    idx = first_unused
                else:
                    idx, update_param, h = first_invalid, True, 0
            else:
                idx = matching
        elif first_unused != -1:
            idx, update_param = first_unused, True
        else:
            idx, update_param = first_invalid, True
        if idx == -1 or FIRST_EXTERNAL_NAV_STATE + idx in self.modes:
            return -1
        if update_param:
            self.hashes[idx] = h
        self.modes[FIRST_EXTERNAL_NAV_STATE + idx] = mode
        return FIRST_EXTERNAL_NAV_STATE + idx

    def _remove_mode(self, nav_state: int, name: str) -> bool:
        mode = self.modes.get(nav_state)
        if mode is not None and mode.name == name:
            del self.modes[nav_state]
            return True
        self.log.append((self.checks.now, f"trying to remove invalid mode {name}"))
        return False

    def _remove_executor(self, executor_id: int) -> None:
        if executor_id == -1:
            return
        if self._in_charge == executor_id:
            self._in_charge = AUTOPILOT_EXECUTOR_ID
        self.executors.pop(executor_id, None)

    # ------------------------------------------------------------ the commander cycle
    def update(self, now: float, armed: bool, user_intended_nav_state: int) -> UpdateRequest:
        """ModeManagement::update (ExternalChecks::update first)."""
        req = UpdateRequest()
        out = self.checks.update(now)
        if out is not None:
            self.requests_out.append(out)
        if armed and not self.allow_update_while_armed:
            if self.requests:   # one per cycle, refused; unregistrations wait for the disarm
                r = self.requests.popleft()
                self.log.append((now, "Not accepting registration requests while armed"))
                self.replies_out.append(RegisterReply(int(r.request_id), name_of(r.name), False, -1, -1, -1,
                                                      False))
            return req
        for ns, mode in list(self.modes.items()):
            if user_intended_nav_state != ns and self.checks.is_unresponsive(mode.arming_check_registration_id):
                self.log.append((now, f"Removing unresponsive mode {ns}"))
                self.checks.remove(mode.arming_check_registration_id, ns)
                self._remove_executor(mode.mode_executor_registration_id)
                self._remove_mode(ns, mode.name)
        self._new_registrations(req)
        self._unregistrations(user_intended_nav_state, req)
        return req

    def _new_registrations(self, req: UpdateRequest) -> None:
        """ModeManagement::checkNewRegistrations."""
        budget = 5
        while not req.change_user_intended_nav_state and self.requests and budget > 0:
            budget -= 1
            r = self.requests.popleft()
            name = name_of(r.name)
            mode_id = executor_id = check_id = -1
            ok = not (r.register_mode_executor and not r.register_mode) \
                and not (r.register_mode and not r.register_arming_check)
            if ok:
                if r.register_arming_check and not self.checks.has_free():
                    ok = False
                if r.register_mode:
                    if len(self.modes) >= MAX_MODES:
                        ok = False
                    elif r.enable_replace_internal_mode and any(
                            m.replaces_nav_state == int(r.replace_internal_mode) for m in self.modes.values()):
                        self.log.append((self.checks.now, "Trying to replace an already replaced mode "
                                         f"({int(r.replace_internal_mode)})"))
                        ok = False
                if r.register_mode_executor and len(self.executors) >= MAX_EXECUTORS:
                    ok = False
            if ok:
                if r.register_mode:
                    replaces = int(r.replace_internal_mode) if r.enable_replace_internal_mode else REPLACES_NONE
                    mode_id = self._add_mode(ExtMode(name, replaces))
                if r.register_mode_executor:
                    executor_id = next(i for i in range(FIRST_EXECUTOR_ID, FIRST_EXECUTOR_ID + MAX_EXECUTORS)
                                       if i not in self.executors)
                    self.executors[executor_id] = mode_id
                    if mode_id != -1:
                        self.modes[mode_id].mode_executor_registration_id = executor_id
                if r.register_arming_check:
                    replaces_ns = int(r.replace_internal_mode) if r.enable_replace_internal_mode else -1
                    check_id = self.checks.add(mode_id, replaces_ns)
                    if mode_id != -1:
                        self.modes[mode_id].arming_check_registration_id = check_id
                if r.register_mode_executor and r.activate_mode_immediately and mode_id != -1:
                    req.change_user_intended_nav_state = True
                    req.user_intended_nav_state = mode_id
            self.replies_out.append(RegisterReply(int(r.request_id), name, ok, check_id, mode_id, executor_id,
                                                  bool(r.not_user_selectable)))

    def _unregistrations(self, user_intended_nav_state: int, req: UpdateRequest) -> None:
        """ModeManagement::checkUnregistrations."""
        budget = 5
        while not req.change_user_intended_nav_state and self.unregisters and budget > 0:
            budget -= 1
            u = self.unregisters.popleft()
            name = name_of(u.name)
            if int(u.arming_check_id) != -1:
                self.checks.remove(int(u.arming_check_id), int(u.mode_id))
            if int(u.mode_id) != -1:
                if self._remove_mode(int(u.mode_id), name):
                    self._remove_executor(int(u.mode_executor_id))
                if user_intended_nav_state == int(u.mode_id):
                    req.change_user_intended_nav_state = True
                    req.user_intended_nav_state = NAV_AUTO_LOITER

    def check_and_report(self) -> Report:
        """The 10 Hz health and arming checks' external part (Commander.cpp: checks at 10 Hz or on change)."""
        report = Report()
        self.checks.check_and_report(report)
        self.report = report
        return report

    # ------------------------------------------------------------ the commander's questions
    def on_user_intention_change(self, from_executor: bool, nav_state: int) -> None:
        """ModeManagement::onUserIntendedNavStateChange."""
        owner = self.modes[nav_state].mode_executor_registration_id if nav_state in self.modes else -1
        if owner == -1:
            if not from_executor:
                self._in_charge = AUTOPILOT_EXECUTOR_ID
        else:
            self._in_charge = owner

    def replacement_if_valid(self, nav_state: int, report_error: bool = True) -> int:
        """getNavStateReplacementIfValid: the responsive replacement of an internal mode, else itself."""
        for ns, mode in self.modes.items():
            if mode.replaces_nav_state == nav_state:
                if self.checks.is_unresponsive(mode.arming_check_registration_id):
                    if not mode.unresponsive_reported and report_error:
                        mode.unresponsive_reported = True
                        self.log.append((self.checks.now, "External mode is unresponsive, falling back to internal"))
                    return nav_state
                return ns
        return nav_state

    def replaced_mode_if_any(self, nav_state: int) -> int:
        mode = self.modes.get(nav_state)
        if mode is not None and mode.replaces_nav_state != REPLACES_NONE:
            return mode.replaces_nav_state
        return nav_state

    def on_disarm(self, stored_nav_state: int) -> int:
        """ModeManagement::onDisarm: the executor's own mode, or Hold for an unresponsive one."""
        nav = stored_nav_state
        if self._in_charge in self.executors:
            nav = self.executors[self._in_charge]
        mode = self.modes.get(nav)
        if mode is not None and self.checks.is_unresponsive(mode.arming_check_registration_id):
            nav = NAV_AUTO_LOITER
        self.on_user_intention_change(False, nav)
        return nav

    def executor_in_charge(self) -> int:
        return AUTOPILOT_EXECUTOR_ID if self.failsafe_action_active else self._in_charge

    def nav_state_display(self, nav_state: int) -> int:
        owner = self.executor_in_charge()
        return self.executors[owner] if owner in self.executors else nav_state

    def mode_status(self, valid_mask: int, can_set_mask: int) -> tuple[int, int]:
        """getModeStatus: every external nav_state valid; registered ones settable; replaced ones hidden."""
        for ns in range(FIRST_EXTERNAL_NAV_STATE, LAST_EXTERNAL_NAV_STATE + 1):
            valid_mask |= 1 << ns
            mode = self.modes.get(ns)
            if mode is not None:
                can_set_mask |= 1 << ns
                if mode.replaces_nav_state != REPLACES_NONE:
                    can_set_mask &= ~(1 << mode.replaces_nav_state)
        return valid_mask, can_set_mask

    def is_unresponsive(self, nav_state: int) -> bool:
        mode = self.modes.get(nav_state)
        return mode is not None and self.checks.is_unresponsive(mode.arming_check_registration_id)
