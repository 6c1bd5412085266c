"""ZenohSimulator: the MAVLink simulator's vehicle speaking PX4's Zenoh protocol instead of MAVLink.

It is what PX4 SITL built with its ``zenoh`` module (``px4_sitl_zenoh``) looks like on the wire
(px4_zenoh_traces): a Zenoh CLIENT (zenoh-pico in PX4) that connects to a router, retrying every
5 s until one is there; PX4's 47 liveliness tokens minus the topics whose types are not bundled
(``px4_table.DECLARED``, ``left_out``); every ``/fmu/out`` sample with PX4's payload (CDR + leftover
bytes) and attachment (seq from 1, µs since boot on a 4 ms grid, PX4's GID) at PX4's rates.

The vehicle is px4_link.sim's ``SimulatorBase``: the same Commander (modes, arming, offboard rules, land
detection, auto-disarm), Failsafes, ParamStore, PointMassQuad, faults and introspection properties as the
MAVLink simulator, its commander extended with PX4's external-mode management (``ext_commander.py``,
``mode_management.py``: registration, the 300 ms arming check, fallbacks, executors); this module is the
Zenoh front end, including the external-mode topics and this PX4's misrouting of three of them
(``MISROUTED_TO``).
Inbound, as PX4 does: ``vehicle_command`` for target system 0 or ours (component 0 or 1), others
dropped silently; one ACK addressed to the command's source ids, ``from_external`` false;
``offboard_control_mode`` is the offboard signal and ``trajectory_setpoint`` its target; attachments
and ``timestamp`` are ignored, trailing bytes accepted, samples over 512 bytes dropped (zenoh-pico's
fragment limit). After boot, PX4's stray DO_GRIPPER (211) ACKs: IN_PROGRESS at ~0.13 s, ACCEPTED at
~1.23 s, to target ids that change per run.

Threading: one loop thread runs everything on a 4 ms tick (PX4 SITL's 250 Hz); Zenoh's threads only
append inbound bytes to a bounded queue. Introspection properties may be read from any thread.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import random
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import zenoh

from px4_link.sim.base import DEFAULT_HOME, SimulatorBase
from px4_link.sim.commander import (
    ACCEPTED,
    CMD_COMPONENT_ARM_DISARM,
    ON_GROUND,
    PX4_ESTIMATOR_WARMUP_S,
    TEMPORARILY_REJECTED,
    ReceivedSetpoint,
)
from px4_link.sim.failsafe import Failsafes
from px4_link.sim.faults import Fault
from px4_zenoh.topics import (
    CHECK_REPLY,
    CHECK_REQUEST,
    COMMAND_ACK,
    COMMAND_MODE_EXECUTOR,
    CONFIG_CONTROL_SETPOINTS,
    CONFIG_OVERRIDES_REQUEST,
    CONTROL_MODE,
    GOTO,
    MODE_COMPLETED_IN,
    MODE_COMPLETED_OUT,
    OFFBOARD_MODE,
    OUT,
    REGISTER_REPLY,
    REGISTER_REQUEST,
    TRAJECTORY,
    UNREGISTER,
    VEHICLE_COMMAND,
    Px4Topic,
)
from px4_zenoh.uorb import UorbCodec, load_types

from .ext_commander import ExtCommander
from .mode_management import API_VERSION, CheckReply, ModeManagement, name_of
from .outlet import Outlet
from .px4_table import DECLARED, ON_CHANGE, PAYLOAD_LEN, RATE_SETS
from .tokens import entity_token, node_token, token_zid
from .uorb_out import (
    NAV_STATE,
    REASON_COMMAND_EXTERNAL,
    REASON_FAILSAFE,
    REASON_LANDING,
    REASON_PREFLIGHT_INACTION,
    UserIntention,
    VehicleView,
    nav_state,
)

log = logging.getLogger(__name__)

TICK_S = 0.004                 # PX4 SITL's 250 Hz loop: its timestamps are multiples of 4000 µs
RETRY_S = 5.0                  # zenoh-pico's reconnect period (src/modules/zenoh)
MAX_INBOUND_BYTES = 512        # zenoh-pico built with a 512 B fragmented-message limit
# px4_zenoh_traces loss: last setpoint -> failsafe_flags.offboard_control_signal_lost 1.084 s,
# -> AUTO_RTL 1.096 s, with COM_OF_LOSS_T 1.0.
SIGNAL_LOST_LATENCY_S = 0.084
FAILSAFE_LATENCY_S = 0.1
STRAY_ACKS = ((0.132, 5, 255), (1.228, ACCEPTED, 0))   # (s after boot, result, result_param1) of cmd 211
CMD_DO_GRIPPER = 211
INBOX_CAP = 2048
SETPOINT_LOG_CAP = 8192   # trajectory_setpoints kept in ``setpoint_arrivals`` (400 s at 20 Hz)
COMPONENT_MODE_EXECUTOR_START = 1000   # VehicleCommand COMPONENT_MODE_EXECUTOR_START
# What the simulator subscribes to (PX4 subscribes to every /fmu/in topic; these are the ones it acts on).
INBOUND = (OFFBOARD_MODE.name, TRAJECTORY.name, VEHICLE_COMMAND.name, REGISTER_REQUEST.name, UNREGISTER.name,
           CHECK_REPLY.name, MODE_COMPLETED_IN.name, GOTO.name, CONFIG_CONTROL_SETPOINTS.name,
           CONFIG_OVERRIDES_REQUEST.name, COMMAND_MODE_EXECUTOR.name)
# Published on events, not on a rate.
EVENT_OUT = (COMMAND_ACK.name, REGISTER_REPLY.name, CHECK_REQUEST.name, MODE_COMPLETED_OUT.name, CONTROL_MODE.name)
# PX4 main 2026-03's zenoh module publishes these /fmu/in topics onto the default uORB topic of their type
# (src/modules/zenoh: the subscriber is made from the type, not the topic; topics.json "uorb_topic").
MISROUTED_TO = {CONFIG_CONTROL_SETPOINTS.name: "vehicle_control_mode",
                CONFIG_OVERRIDES_REQUEST.name: "config_overrides", COMMAND_MODE_EXECUTOR.name: "vehicle_command"}


class ZenohSimulator(SimulatorBase):
    """A PX4 SITL (zenoh build) stand-in; ``connect`` is the router PX4 joins as a client."""

    THREAD_PREFIX: ClassVar[str] = "px4zsim"
    ERROR_LABEL: ClassVar[str] = "zenoh sim"
    JOIN_TIMEOUT_S: ClassVar[float] = 5.0
    _log: ClassVar[logging.Logger] = log
    commander: ExtCommander

    def __init__(self, connect: str = "tcp/127.0.0.1:7447", sysid: int = 1, domain: int = 0, *,
                 rates: str = "px4", params: dict[str, float | int] | None = None,
                 home: tuple[float, float, float] = DEFAULT_HOME, physics_hz: float = 100.0,
                 seed: int | None = None, estimator_warmup_s: float = PX4_ESTIMATOR_WARMUP_S,
                 msg_dir: Path | None = None, retry_s: float = RETRY_S, faults: Sequence[Fault] = (),
                 mode_arm_check: bool = False, bridge_fixed: bool = False) -> None:
        if rates not in RATE_SETS:
            raise ValueError(f"rates is one of {', '.join(RATE_SETS)}, got {rates!r}")
        # the types first: loading them takes ~0.1 s, which must not count as time since boot (stray ACKs)
        types = load_types(msg_dir)
        self._types: dict[str, Any] = dict(types)
        self._codecs = {name: UorbCodec.of(cls) for name, cls in types.items()}
        # PX4's topics whose types we have; the rest of PX4's 46 entities are left out (no definition,
        # so no hash to announce and nothing to encode).
        self.declared: tuple[Px4Topic, ...] = tuple(t for t in DECLARED if t.type_short in types)
        self.left_out: tuple[Px4Topic, ...] = tuple(t for t in DECLARED if t.type_short not in types)
        super().__init__(sysid, params=params, home=home, physics_hz=physics_hz, seed=seed,
                         estimator_warmup_s=estimator_warmup_s, faults=faults,
                         offboard_loss_latency_s=FAILSAFE_LATENCY_S)
        # PX4's commander with its external-mode management (ext_commander.py, mode_management.py);
        # mode_arm_check is COM_MODE_ARM_CHK (registrations accepted while armed).
        self.commander = ExtCommander(self.params, self.vehicle, self._boot, home_alt=home[2],
                                      estimator_warmup_s=estimator_warmup_s,
                                      offboard_loss_latency_s=FAILSAFE_LATENCY_S,
                                      mm=ModeManagement(allow_update_while_armed=mode_arm_check))
        self.failsafes = Failsafes(self.params, self.commander)
        self.connect, self.domain = connect, domain
        # bridge_fixed: a PX4 with PR #26564, whose zenoh module maps the three MISROUTED_TO topics by name: an
        # executor's commands reach Commander::handleCommandsFromModeExecutors (the in-charge check); the two
        # config topics reach their own uORB topics, which this simulator records (``delivered``) but does not
        # model (no control-config or override handling).
        self.bridge_fixed = bridge_fixed
        self.delivered: dict[str, int] = {name: 0 for name in MISROUTED_TO}
        self.rates = dict(RATE_SETS[rates])
        self.retry_s = retry_s
        self.view = VehicleView(types, self.commander, self.vehicle, self.failsafes, home, sysid,
                                UserIntention(self.commander.mode))
        self._rng = random.Random(seed)
        self._connected = threading.Event()
        self._inbox: deque[tuple[str, bytes, float]] = deque(maxlen=INBOX_CAP)
        self._outlets: dict[str, Outlet] = {}
        self._due_us: dict[str, int] = {}
        self._last_sig: dict[str, tuple[Any, ...]] = {}
        self._trajectory: Any = None
        # (Zenoh receive time, position or None) of every trajectory_setpoint: what a latency run matches
        self._setpoint_log: deque[tuple[float, tuple[float, float, float] | None]] = deque(maxlen=SETPOINT_LOG_CAP)
        self._ocm: Any = None
        self._ocm_last: float | None = None
        self._was_armed = False
        self._disarm_commanded = False
        self._stray = list(STRAY_ACKS)
        self._stray_target = (self._rng.randrange(1, 256), self._rng.randrange(1, 256))
        self.zid = ""
        self.token_keys: list[str] = []
        self.published: dict[str, int] = {}
        self.dropped: dict[str, int] = {"oversize": 0, "target": 0, "malformed": 0, "inbox_full": 0}
        self.commands: list[tuple[float, int, int]] = []
        self.connect_attempts = 0
        # external modes: what PX4 would log or publish, for tests
        self.misrouted: dict[str, int] = {name: 0 for name in MISROUTED_TO}
        self.control_mode_overwrites: list[tuple[float, bool]] = []   # (time, flag_armed) PX4 was handed
        self.check_requests: list[tuple[float, int]] = []             # (time, request_id) published
        self.check_replies: list[tuple[float, int, int, bool]] = []   # (time, request_id, registration, can_arm)
        self.registration_log: list[tuple[float, str, int, bool, int]] = []   # (time, name, request_id, ok, mode)
        self.unregister_log: list[tuple[float, str, int]] = []
        self.mode_completed_log: list[tuple[float, int, int]] = []    # (time, nav_state, result)
        self.goto_received = 0
        self.px4_completed_log: list[tuple[float, int]] = []          # (time, nav_state) of PX4's own modes
        self.executor_refusals = 0                                     # executor commands refused (not in charge)

    # ---------------------------------------------------------------- lifecycle
    def wait_connected(self, timeout: float) -> bool:
        return self._connected.wait(timeout)

    # ---------------------------------------------------------------- session
    def _open(self) -> zenoh.Session | None:
        """zenoh-pico in PX4: client mode, the configured locator, a new try every ``retry_s``."""
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["{self.connect}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        while not self._stop.is_set():
            self.connect_attempts += 1
            try:
                return zenoh.open(conf)
            except zenoh.ZError as e:
                log.warning("px4 zenoh sim: Unable to open session, make sure zenohd is running on %s (%s)",
                            self.connect, e)
            self._stop.wait(self.retry_s)
        return None

    def _declare(self, session: zenoh.Session) -> list[Any]:
        self.zid = token_zid(str(session.info.zid()))
        keys = [node_token(self.zid)]
        handles: list[Any] = []
        for topic in self.declared:
            codec = self._codecs[topic.type_short]
            keys.append(entity_token(self.zid, self.domain, topic, codec.type_hash))
            key = topic.key(self.domain, codec.type_hash)
            if topic.direction == OUT and (topic.name in self.rates or topic.name in EVENT_OUT):
                self._outlets[topic.name] = Outlet(session, key, codec, PAYLOAD_LEN[topic.type_short])
            elif topic.name in INBOUND:
                handles.append(session.declare_subscriber(key, self._receiver(topic.name)))
        handles += [session.liveliness().declare_token(k) for k in keys]
        self.token_keys = keys
        return handles

    def _receiver(self, name: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:   # Zenoh's thread: size check and hand-off only
            if len(sample.payload) > MAX_INBOUND_BYTES:
                self.dropped["oversize"] += 1
                return
            if len(self._inbox) == INBOX_CAP:
                self.dropped["inbox_full"] += 1
            self._inbox.append((name, sample.payload.to_bytes(), time.monotonic()))
        return on_sample

    # ---------------------------------------------------------------- loop
    def _run(self) -> None:
        session = self._open()
        if session is None:
            return
        handles: list[Any] = []
        try:
            with self._lock:
                handles = self._declare(session)
            self._connected.set()
            log.info("px4 zenoh sim %d: session %s on %s, %d tokens", self.sysid, self.zid, self.connect,
                     len(self.token_keys))
            self._loop()
        except Exception:
            self._internal_error(f"session: {traceback.format_exc()}")
        finally:
            self._connected.clear()
            for h in handles:
                try:
                    h.undeclare()
                except Exception:   # the session may already be closing; nothing left to release
                    pass
            for o in self._outlets.values():
                o.undeclare()
            self._outlets.clear()
            session.close()

    def _loop(self) -> None:
        next_phys = next_tick = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            t_us = int((now - self._boot) / TICK_S) * 4000
            with self._lock:
                try:
                    self._drain(now, t_us)
                    next_phys = self._advance(now, next_phys)
                    self._after_physics(now)
                    self._publish(now, t_us)
                except Exception:
                    self._internal_error(f"loop: {traceback.format_exc()}")
            next_tick += TICK_S
            if next_tick <= time.monotonic():   # behind (a loaded machine): skip, as PX4 drops cycles
                next_tick = time.monotonic() + TICK_S
            self._stop.wait(max(0.0, next_tick - time.monotonic()))

    def _after_physics(self, now: float) -> None:
        c = self.commander
        texts = [t for _, t in c.statustexts]
        for text in texts:
            log.debug("sim%d: %s", self.sysid, text)
        c.statustexts.clear()
        c.take_outgoing()   # gimbal commands: PX4's zenoh build publishes no vehicle_command out
        if self._was_armed and not c.armed:
            self.view.disarm_reason = (REASON_LANDING if "Disarmed: landed" in texts
                                       else REASON_PREFLIGHT_INACTION if any("no takeoff" in t for t in texts)
                                       else REASON_COMMAND_EXTERNAL if self._disarm_commanded else REASON_FAILSAFE)
        self._was_armed = c.armed
        self._disarm_commanded = False
        self.view.intention.update(c)
        recent = self._ocm_last is not None and \
            now - self._ocm_last <= float(self.params["COM_OF_LOSS_T"]) + SIGNAL_LOST_LATENCY_S
        self.view.offboard_signal_lost = not (recent and c.estimate_valid())

    # ---------------------------------------------------------------- inbound
    def _drain(self, now: float, t_us: int) -> None:
        while self._inbox:
            name, payload, t_rx = self._inbox.popleft()
            try:
                if name == COMMAND_MODE_EXECUTOR.name and self.bridge_fixed:
                    self.delivered[name] += 1
                    self._on_executor_command(self._codecs["VehicleCommand"].decode(payload), t_rx, t_us)
                elif name in (VEHICLE_COMMAND.name, COMMAND_MODE_EXECUTOR.name):
                    if name == COMMAND_MODE_EXECUTOR.name:   # misrouted: commander sees a plain vehicle_command
                        self.misrouted[name] += 1
                    self._on_command(self._codecs["VehicleCommand"].decode(payload), t_rx, t_us)
                elif name == OFFBOARD_MODE.name:
                    self._on_offboard_mode(self._codecs["OffboardControlMode"].decode(payload), t_rx)
                elif name == TRAJECTORY.name:
                    self._on_trajectory(self._codecs["TrajectorySetpoint"].decode(payload), t_rx)
                else:
                    self._on_external(name, payload, t_rx, t_us)
            except ValueError as e:   # PX4 reads the body blindly; a short sample is simply not a message
                self.dropped["malformed"] += 1
                log.debug("sim%d: dropped %s: %s", self.sysid, name, e)

    def _on_command(self, cmd: Any, t_rx: float, t_us: int) -> None:
        # Commander.cpp handle_command: system and component must be ours or 0, else not for us (silent).
        if cmd.target_system not in (0, self.sysid) or cmd.target_component not in (0, 1):
            self.dropped["target"] += 1
            return
        p = [float(cmd.param1), float(cmd.param2), float(cmd.param3), float(cmd.param4), float(cmd.param5),
             float(cmd.param6), float(cmd.param7)]
        try:
            # Commander.cpp getSourceFromCommand: a mode executor's commands keep it in charge
            self.commander.command_from_executor = int(cmd.source_component) >= COMPONENT_MODE_EXECUTOR_START
            try:
                r = self.commander.handle_command(int(cmd.command), p, t_rx)
            finally:   # only this command's mode change is the executor's
                self.commander.command_from_executor = False
        except Exception:
            # a simulator bug, never an answer: no ACK (a FAILED ACK would pass for a refusal)
            self._internal_error(f"command {cmd.command}: {traceback.format_exc()}")
            return
        if cmd.command == CMD_COMPONENT_ARM_DISARM and r.result == ACCEPTED and int(round(p[0])) == 0:
            self._disarm_commanded = True
        if r.text:
            log.info("sim%d: %s", self.sysid, r.text)
        self.commands.append((t_rx, int(cmd.command), r.result))
        self._send_ack(t_us, int(cmd.command), r.result, int(cmd.source_system), int(cmd.source_component))

    def _on_executor_command(self, cmd: Any, t_rx: float, t_us: int) -> None:
        """Commander::handleCommandsFromModeExecutors (a fixed bridge only): run by the commander when it comes
        from the executor in charge (source_component 1000 + its id), else TEMPORARILY_REJECTED; either way PX4
        sets source_system to its own id first, so the ACK goes to (our system id, 1000 + id)."""
        cmd = dataclasses.replace(cmd, source_system=self.sysid)
        in_charge = self.commander.mm.executor_in_charge()
        if int(cmd.source_component) == COMPONENT_MODE_EXECUTOR_START + in_charge:
            self._on_command(cmd, t_rx, t_us)
            return
        log.warning("sim%d: Got cmd from executor %d not in charge (in charge: %d)", self.sysid,
                    int(cmd.source_component) - COMPONENT_MODE_EXECUTOR_START, in_charge)
        self.executor_refusals += 1
        self._send_ack(t_us, int(cmd.command), TEMPORARILY_REJECTED, self.sysid, int(cmd.source_component))

    def _on_offboard_mode(self, ocm: Any, t_rx: float) -> None:
        self._ocm, self._ocm_last = ocm, t_rx
        self.commander.on_setpoint(self._setpoint(t_rx))

    def _on_trajectory(self, traj: Any, t_rx: float) -> None:
        self._trajectory = traj
        pos = tuple(float(a) for a in traj.position)
        self._setpoint_log.append((t_rx, pos if all(math.isfinite(a) for a in pos) else None))  # type: ignore[arg-type]
        vel = tuple(float(a) for a in traj.velocity)
        self.commander.on_external_setpoint(
            pos if all(math.isfinite(a) for a in pos) else None,  # type: ignore[arg-type]
            vel if all(math.isfinite(a) for a in vel) else None,  # type: ignore[arg-type]
            float(traj.yaw) if math.isfinite(traj.yaw) else None, goto=False)
        last = self.commander.last_setpoint
        if last is not None:   # a new target within the current offboard signal (its time unchanged)
            self.commander.last_setpoint = dataclasses.replace(self._setpoint(last.time), time=last.time)

    def _setpoint(self, t: float) -> ReceivedSetpoint:
        ocm, traj = self._ocm, self._trajectory
        pos = vel = yaw = None
        if traj is not None and ocm is not None:
            p, v = tuple(float(a) for a in traj.position), tuple(float(a) for a in traj.velocity)
            if ocm.position and all(math.isfinite(a) for a in p):
                pos = p
            if (ocm.position or ocm.velocity) and all(math.isfinite(a) for a in v):
                vel = v
            yaw = float(traj.yaw) if math.isfinite(traj.yaw) else None
        mask = (0x7 if pos is None else 0) | (0x38 if vel is None else 0) | 0x1C0 | (0x400 if yaw is None else 0) \
            | 0x800
        return ReceivedSetpoint(t, mask, 1, pos, vel, yaw, 0)  # type: ignore[arg-type]

    def _on_external(self, name: str, payload: bytes, t_rx: float, t_us: int) -> None:
        """The external-mode topics; the uORB queue each lands in is ModeManagement's (its lengths)."""
        mm = self.commander.mm
        if name == REGISTER_REQUEST.name:
            mm.requests.append(self._codecs["RegisterExtComponentRequest"].decode(payload))
        elif name == UNREGISTER.name:
            u = self._codecs["UnregisterExtComponent"].decode(payload)
            self.unregister_log.append((t_rx, name_of(u.name), int(u.mode_id)))
            mm.unregisters.append(u)
        elif name == CHECK_REPLY.name:
            reply = self._codecs["ArmingCheckReply"].decode(payload)
            self.check_replies.append((t_rx, int(reply.request_id), int(reply.registration_id),
                                       bool(reply.can_arm_and_run)))
            mm.checks.replies.append(CheckReply.of(reply))
        elif name == MODE_COMPLETED_IN.name:
            # uORB mode_completed: PX4's own publisher of /fmu/out/mode_completed sends it straight back out
            done = self._codecs["ModeCompleted"].decode(payload)
            self.mode_completed_log.append((t_rx, int(done.nav_state), int(done.result)))
            self._put(MODE_COMPLETED_OUT.name, dataclasses.replace(done, timestamp=t_us), t_us)
        elif name == GOTO.name:
            g = self._codecs["GotoSetpoint"].decode(payload)
            self.goto_received += 1
            pos = tuple(float(a) for a in g.position)
            yaw = float(g.heading) if g.flag_control_heading and math.isfinite(g.heading) else None
            self.commander.on_external_setpoint(pos if all(math.isfinite(a) for a in pos) else None,  # type: ignore[arg-type]
                                                None, yaw, goto=True)
        elif name in (CONFIG_CONTROL_SETPOINTS.name, CONFIG_OVERRIDES_REQUEST.name) and self.bridge_fixed:
            self.delivered[name] += 1   # where it belongs; not modelled (see __init__)
        elif name == CONFIG_CONTROL_SETPOINTS.name:
            # misrouted onto uORB vehicle_control_mode: the controllers (and PX4's own /fmu/out publisher)
            # take the mode's config for commander's control mode until commander publishes again
            cm = self._codecs["VehicleControlMode"].decode(payload)
            self.misrouted[name] += 1
            self.control_mode_overwrites.append((t_rx, bool(cm.flag_armed)))
            self._put(CONTROL_MODE.name, dataclasses.replace(cm, timestamp=t_us), t_us)
        elif name == CONFIG_OVERRIDES_REQUEST.name:
            self.misrouted[name] += 1   # lands on config_overrides, which commander rewrites within 500 ms

    def _mode_management_out(self, t_us: int) -> None:
        mm = self.commander.mm
        for r in mm.replies_out:
            self.registration_log.append((time.monotonic(), r.name, r.request_id, r.success, r.mode_id))
            self._put(REGISTER_REPLY.name, self._types["RegisterExtComponentReply"](
                timestamp=t_us, request_id=r.request_id, name=r.name.encode()[:24].ljust(25, b"\0"),
                px4_ros2_api_version=API_VERSION, success=r.success, arming_check_id=r.arming_check_id,
                mode_id=r.mode_id, mode_executor_id=r.mode_executor_id, not_user_selectable=r.not_user_selectable),
                t_us)
        for q in mm.requests_out:
            self.check_requests.append((time.monotonic(), q.request_id))
            self._put(CHECK_REQUEST.name, self._types["ArmingCheckRequest"](
                timestamp=t_us, request_id=q.request_id, valid_registrations_mask=q.valid_registrations_mask), t_us)
        mm.replies_out.clear()
        mm.requests_out.clear()
        for nav in self.commander.completions:   # PX4's own modes' mode_completed (navigator)
            self.px4_completed_log.append((time.monotonic(), nav))
            self._put(MODE_COMPLETED_OUT.name, self._types["ModeCompleted"](timestamp=t_us, result=0, nav_state=nav),
                      t_us)
        self.commander.completions.clear()

    def _put(self, name: str, msg: Any, t_us: int) -> None:
        outlet = self._outlets.get(name)
        if outlet is not None:
            outlet.put(msg, t_us)
            self.published[name] = self.published.get(name, 0) + 1

    # ---------------------------------------------------------------- outbound
    def _send_ack(self, t_us: int, command: int, result: int, target_system: int, target_component: int,
                  result_param1: int = 0) -> None:
        outlet = self._outlets.get(COMMAND_ACK.name)
        if outlet is not None:
            outlet.put(self.view.command_ack(t_us, command, result, target_system, target_component,
                                             result_param1), t_us)
            self.published[COMMAND_ACK.name] = self.published.get(COMMAND_ACK.name, 0) + 1

    def _signature(self, name: str) -> tuple[Any, ...]:
        c, v = self.commander, self.view
        if name.endswith("vehicle_status"):
            mm = self.commander.mm
            return (nav_state(c.mode), c.armed, c.failsafe, v.intention.mode, c.preflight_failure() is None,
                    mm.executor_in_charge(), tuple(sorted(mm.modes)))
        if name.endswith("vehicle_land_detected"):
            return (c.landed_state == ON_GROUND,)
        if name.endswith("vehicle_control_mode"):
            return (c.mode, c.armed)
        return (v.offboard_signal_lost, c.estimate_valid())

    def _publish(self, now: float, t_us: int) -> None:
        self._mode_management_out(t_us)
        while self._stray and now - self._boot >= self._stray[0][0]:
            _, result, param1 = self._stray.pop(0)
            self._send_ack(t_us, CMD_DO_GRIPPER, result, *self._stray_target, result_param1=param1)
        for name, hz in self.rates.items():
            outlet = self._outlets.get(name)
            if outlet is None or hz <= 0:
                continue
            builder: Callable[[int], Any] = getattr(self.view, name.rsplit("/", 1)[1])
            period = int(1e6 / hz)
            due = self._due_us.get(name, t_us)
            sent = 0
            # a late tick publishes what PX4 would have (up to 3 samples), so rates hold under load
            while due <= t_us and sent < 3:
                outlet.put(builder(due // 4000 * 4000), due // 4000 * 4000)
                due += period
                sent += 1
            if due <= t_us:
                due = t_us + period
            self._due_us[name] = due
            if name in ON_CHANGE:
                sig = self._signature(name)
                if sig != self._last_sig.get(name) and not sent:
                    outlet.put(builder(t_us), t_us)
                    sent = 1
                self._last_sig[name] = sig
            self.published[name] = self.published.get(name, 0) + sent

    # ---------------------------------------------------------------- the front end's records
    def _setpoint_record(self) -> list[tuple[float, tuple[float, float, float] | None]]:
        """Each trajectory_setpoint, at the time Zenoh delivered it."""
        return list(self._setpoint_log)

    def _command_record(self) -> list[tuple[float, int, int]]:
        return list(self.commands)

    # ---------------------------------------------------------------- introspection (Zenoh's own)
    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def nav_state(self) -> int:
        return NAV_STATE.get(self.commander.mode, 4)

    @property
    def mode_management(self) -> ModeManagement:
        """PX4's external-mode state (read under no lock: for tests and logs)."""
        return self.commander.mm

    @property
    def offboard_signal_lost(self) -> bool:
        return self.view.offboard_signal_lost
