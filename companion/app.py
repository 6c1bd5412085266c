"""The companion: Zenoh on one side, PX4 over MAVLink on the other.

Setpoints in (``<id>/setpoint``, DroneSetpoint) -> px4_link's offboard stream, but only
inside an operator-requested offboard session (companion/offboard.py) and only from the
GCS in control (companion/control.py). PX4 telemetry out: ``<id>/sensor``
(SensorCombined from HIGHRES_IMU), ``<id>/state`` (VehicleState, with the offboard
lifecycle, the controller and the sensor rate PX4 really delivers), camera frames on
``<id>/image``, events on ``<id>/events`` (FailsafeEvent: failsafes, lifecycle
transitions, refused setpoints and commands, rate-limited). Commands arrive on the
``<id>/command`` service; every one is logged with its sender and every refusal says why.

Link-loss failsafe: when setpoints from the controller stop for ``setpoint_deadline``
while a session is active, the companion commands PX4 HOLD (AUTO.LOITER), then stops
streaming, and publishes a FailsafeEvent. It resumes only on an explicit
``offboard_start``, from setpoints near the vehicle's current position (or by itself with
``resume_on_setpoints``, under the same checks).
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import zenoh

from drone_contract.commands import COMMANDS
from drone_contract.limits import COMPANION_DEADLINE_S, CONTROL_LEASE_S, MAX_OFFSET_M, MAX_SPEED_MS
from drone_contract.messages import (
    CONTROL_TOKEN_PREFIX,
    Command,
    CommandResult,
    DroneSetpoint,
    FailsafeEvent,
    VehicleState,
    valid_client_id,
)
from drone_contract.streams import StreamProfile, stream_profile
from px4_link import Px4Link
from px4_link.commands import CommandError, CommandTimeout, NotConnected
from px4_link.setpoints import PositionSetpoint, Setpoint, SetpointRejected, VelocitySetpoint
from px4_link.telemetry import Attitude, Battery, Imu, LocalPosition
from px4_link.wire import message_id
from zenoh_robot import Node
from zenoh_robot.events import SubscriptionEventCallbacks
from zenoh_robot.image_fec import FecImagePublisher
from zenoh_robot.image_transport import MAX_SLICES, ImagePublisher, encode_strip
from zenoh_robot.loss_feedback import LinkMonitor
from zenoh_robot.msgs import Header, Image, SensorCombined
from zenoh_robot.publisher import PublisherClosed
from zenoh_robot.tools.stream_metrics import StreamRecorder
from zenoh_robot.topic_statistics import with_cpu_budget

from .camera import RateKeeper, open_source
from .control import ControlArbiter
from .offboard import SAFE_MODE, OffboardLifecycle, OffboardState, Refused, VehicleMotion, check_against_vehicle
from .params import PX4_STREAMS, CompanionParameters
from .reporting import RateLimiter

log = logging.getLogger("companion")

# Parameters a GCS may set by default: speeds and takeoff/landing behaviour, never failsafes or geofence.
DEFAULT_PARAM_ALLOW = ("MPC_XY_VEL_MAX", "MPC_XY_CRUISE", "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN",
                       "MPC_TKO_SPEED", "MPC_LAND_SPEED", "MIS_TAKEOFF_ALT")
# Executor % of one core the setpoint subscription may take (`zenoh-robot stats`, issue #18): 10 Hz
# of setpoints with their copies measured 0.4 % (median, quiet host; max 0.7): 1.5 leaves room for
# a loaded host and still flags a slow callback or a flood.
SETPOINT_CPU_BUDGET_PCT = 1.5

# PX4's streams (issue #18). On an onboard link PX4 sends ~240 messages/s in the simulator (~490
# from real SITL) by default, and packing (simulator) and parsing (px4link-rx) them was most of a
# companion's CPU. px4_streams "lean" asks, when the link comes up, for what the companion and
# px4_link read, at the rate each is needed, and switches off what nothing reads; px4_link asks
# again after a PX4 reconnect or reboot (PX4 forgets). HIGHRES_IMU is asked on its own
# (sensor_rate_hz). The rates, and why:
LEAN_STREAMS_HZ: dict[str, float] = {
    # VehicleState's attitude, sampled at 5 Hz: at 10 Hz it is at most 100 ms old. The reboot
    # watch (px4_link/rates.py BootWatch) needs no particular rate: see JUMP_MS there.
    "ATTITUDE": 10.0,
    # VehicleState's position, and the setpoint offset checks (check_against_vehicle, px4_link's
    # jump check), which want it fresh within ~100 ms: at 20 Hz it is <= 50 ms old, room for jitter.
    "LOCAL_POSITION_NED": 20.0,
    # Only takeoff reads it (home AMSL = alt - relative_alt, which does not move): 1 Hz.
    "GLOBAL_POSITION_INT": 1.0,
    # Read by nothing: off (interval -1). Those after GPS_RAW_INT are real PX4's only (the
    # simulator ACKs them as PX4 does and sends none of them anyway).
    "VFR_HUD": 0.0, "GPS_RAW_INT": 0.0,
    "ATTITUDE_QUATERNION": 0.0, "ODOMETRY": 0.0, "ALTITUDE": 0.0, "DISTANCE_SENSOR": 0.0,
    "ATTITUDE_TARGET": 0.0, "POSITION_TARGET_LOCAL_NED": 0.0, "POSITION_TARGET_GLOBAL_INT": 0.0,
    "SERVO_OUTPUT_RAW": 0.0,
}
# Not asked, PX4's defaults fit: EXTENDED_SYS_STATE 5 Hz (landed state: VehicleState, forced-disarm
# check), BATTERY_STATUS 0.5 Hz (VehicleState's battery), SYS_STATUS 5 Hz, SYSTEM_TIME / TIMESYNC
# (PX4's own link protocol, 1 / 10 Hz), HEARTBEAT (no stream: PX4 refuses an interval for it).
# With the MAVLink tunnel nothing is cut: QGC draws attitude and position from PX4's default streams.
SUMMARY_STREAMS = ("HIGHRES_IMU", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "VFR_HUD",
                   "GPS_RAW_INT", "SYS_STATUS", "EXTENDED_SYS_STATE", "BATTERY_STATUS")


def ask_streams(link: Px4Link, plan: dict[str, float]) -> dict[str, str]:
    """Ask PX4 for each stream of ``plan`` at its rate (0: off); returns {stream: why} for those
    not applied. All are remembered first, so px4_link asks for every one again after a PX4
    reconnect or reboot even when this round stopped early."""
    for name, hz in plan.items():
        link.telemetry.intervals.remember(message_id(name), hz)
    refused: dict[str, str] = {}
    names = list(plan)
    for i, name in enumerate(names):
        try:
            link.telemetry.request_message_interval(name, plan[name])
        except (CommandTimeout, NotConnected) as exc:
            # PX4 silent or gone: not 4 s more per stream on the command worker; asked again
            # when it comes back.
            refused.update({n: f"not asked: {exc}" for n in names[i:]})
            break
        except CommandError as exc:   # refused (a PX4 build without that stream): its default stays
            refused[name] = str(exc)
    return refused


@dataclass
class CompanionConfig:
    drone_id: str = "uav1"
    profile: StreamProfile = field(default_factory=lambda: stream_profile("resilient"))
    setpoint_deadline: float = COMPANION_DEADLINE_S
    resume_on_setpoints: bool = False
    sensor_rate_hz: float = 200.0        # the thesis's SensorCombined rate; asked of PX4 via MAVLink
    sensor_rate_tolerance: float = 0.9   # warn when PX4 delivers less than this share of it
    state_rate_hz: float = 5.0
    camera: str | None = "test"          # None: no images
    camera_rate_hz: float = 30.0
    image_width: int = 320
    image_height: int = 240
    max_offset_m: float = MAX_OFFSET_M   # how far a position target may lie from the vehicle
    max_speed: float = MAX_SPEED_MS      # velocity setpoints, m/s
    control_lease_s: float = CONTROL_LEASE_S   # a controller without liveliness token is gone after this silence
    allow_force_disarm: bool = False     # a forced disarm in flight drops the vehicle
    param_allow: tuple[str, ...] = DEFAULT_PARAM_ALLOW
    report_interval_s: float = 2.0       # repeated refusals: one event per key per interval
    px4_streams: str = "lean"            # lean: only the PX4 streams read (LEAN_STREAMS_HZ); default: PX4's
    mavlink_tunnel: bool = False         # a QGC reads PX4's streams through the tunnel: nothing is cut
    qos_overrides: dict[str, Any] = field(default_factory=dict)   # -p reliability/history/depth, as given


@dataclass
class Candidate:
    """The latest setpoint from one client while no session forwards it: where offboard_start begins."""
    sp: Setpoint | None
    at: float
    refused: str = ""        # why the latest one was refused, "" when it passed the checks


class Companion:
    MAX_CANDIDATES = 16

    def __init__(self, node: Node, link: Px4Link, config: CompanionConfig) -> None:
        # First: every setting below is read from the parameters in force (-p wins over the flag).
        self.params = CompanionParameters(config)
        config = self.params.declare(node)
        self.node, self.link, self.config = node, link, config
        q = config.profile.qos
        self.setpoints = StreamRecorder()
        # image_strip: every strip (FEC: every frame) sent, as frame * MAX_SLICES + index, for the
        # experiment's fresh-strip fraction.
        self.sent = {name: StreamRecorder() for name in ("sensor", "state", "image", "image_strip")}
        self.setpoints_rejected = 0
        self.setpoints_ignored = 0        # valid but outside a session: kept as candidate only
        self.commands_refused = 0
        self.failsafe = ""                # why we hold, or ""
        self.last_setpoint_at = 0.0       # last setpoint forwarded to PX4 inside a session
        self.events_sent: list[str] = []
        self._candidates: dict[str, Candidate] = {}
        self._lock = threading.Lock()
        self._limiter = RateLimiter(config.report_interval_s)
        self._rate_since = time.monotonic()
        self.sensor_rate_requested = config.sensor_rate_hz
        self.px4_streams = self._streams_in_force(config)
        self.streams_asked = dict(LEAN_STREAMS_HZ) if self.px4_streams == "lean" else {}
        self.streams_refused: dict[str, str] = {}   # stream -> why; bounded by the plan
        self._sensor_low_warned = 0.0
        self._park_sent = 0.0
        self._resume_tried = 0.0
        # PX4 commands wait for an ACK (up to seconds): never on the executor's threads.
        # One worker: lifecycle transitions and commands run in order, never concurrently.
        self._commands = ThreadPoolExecutor(max_workers=1, thread_name_prefix="px4-cmd")
        self.control = ControlArbiter(config.control_lease_s)
        self.lifecycle = OffboardLifecycle(link, self._on_transition)

        self.sensor_pub = node.create_publisher(SensorCombined, "sensor", q["sensor"])
        self.state_pub = node.create_publisher(VehicleState, "state", q["state"])
        self.events_pub = node.create_publisher(FailsafeEvent, "events", q["events"])
        self.image_pub: Any = None
        if config.camera:
            if config.profile.image_mode == "sliced":
                self.image_pub = ImagePublisher(node, "image", q["image"], quality=config.profile.jpeg_quality)
            elif config.profile.image_mode == "fec":
                self.image_pub = FecImagePublisher(node, "image", q["image"], quality=config.profile.jpeg_quality)
            else:
                self.image_pub = node.create_publisher(Image, "image", q["image"])
        # Loss feedback (loss_feedback.py): image parity follows the loss the GCS measures.
        self.link_monitor = LinkMonitor(node) if config.profile.loss_feedback else None
        if self.link_monitor is not None and isinstance(self.image_pub, FecImagePublisher):
            self.link_monitor.adapt(self.image_pub.set_loss)
        self.setpoint_sub = node.create_subscription(
            DroneSetpoint, "setpoint", self._on_setpoint, q["setpoint"].replace(deadline=config.setpoint_deadline),
            event_callbacks=SubscriptionEventCallbacks(deadline=self._on_deadline_missed),
            topic_statistics=with_cpu_budget(node.enable_topic_statistics, SETPOINT_CPU_BUDGET_PCT))
        command_srv = node.create_service("command", Command, CommandResult, self._on_command)
        if self.link_monitor is not None:   # reply copies sized from the measured loss (services.py)
            self.link_monitor.adapt(command_srv.set_loss)
        node.create_timer(1.0 / config.state_rate_hz, self._publish_state)
        # The QoS deadline event is the trigger; this watchdog is its backstop, checked at 20 Hz,
        # so the failsafe never depends on one mechanism alone. It also checks the invariants.
        node.create_timer(0.05, self._watchdog)
        self._tokens = node.session.liveliness().declare_subscriber(
            f"{CONTROL_TOKEN_PREFIX}/*", self._on_token, history=True)
        link.telemetry.add_listener(self._on_imu, Imu)
        link.add_event_listener(self._on_link_event)
        self._stop = threading.Event()
        self._camera_seq = 0   # the frame's header.seq, as a camera driver numbers its frames
        self._camera_thread: threading.Thread | None = None
        if config.camera:
            self._camera_thread = threading.Thread(target=self._camera_loop, name="camera", daemon=True)
            self._camera_thread.start()
        self.params.on_change = self._on_params_changed
        node.add_on_close(self.close)

    # -- events ------------------------------------------------------------------------
    def _event(self, kind: str, detail: str, action: str = "", client_id: str = "", count: int = 0) -> None:
        log.warning("%s%s: %s -> %s", kind, f" [{client_id}]" if client_id else "", detail, action or "no action")
        self.events_sent.append(kind)
        del self.events_sent[:-200]
        try:
            self.events_pub.publish(FailsafeEvent(Header.now(), kind, detail, action, client_id, count))
        except PublisherClosed:
            pass

    def _on_transition(self, old: OffboardState, new: OffboardState, why: str) -> None:
        self._event("lifecycle", f"{old.value} -> {new.value}: {why}", new.value)

    def _report_refused(self, kind: str, client_id: str, reason: str, detail: str) -> None:
        """Count always; publish and log the first and then once per interval per (kind, client, reason)."""
        count = self._limiter.hit(kind, client_id, reason)
        if count:
            self._event(kind, detail, "refused", client_id, count)

    # -- setpoints -----------------------------------------------------------------------
    def _on_setpoint(self, msg: DroneSetpoint, info: Any) -> None:
        self.setpoints.record(info.seq, info.source_stamp_ns, info.received_stamp_ns)
        client = msg.client_id if valid_client_id(msg.client_id) else ""
        holder = self.control.holder
        if holder and client != holder or not client:
            _, why, _ = self.control.admit(client, "setpoint")
            self.setpoints_rejected += 1
            self._report_refused("setpoint_rejected", client, "not_in_control", why)
            return
        self.control.seen(client)
        now = time.monotonic()
        try:
            sp = self._to_setpoint(msg)
            check_against_vehicle(sp, self._motion(), self.config.max_offset_m, self.config.max_speed)
        except Refused as exc:
            self._remember(client, None, now, f"{exc}")
            self.setpoints_rejected += 1
            self._report_refused("setpoint_rejected", client, exc.reason, f"setpoint refused: {exc}")
            return
        self._remember(client, sp, now, "")
        try:
            self.lifecycle.forward(sp)
        except Refused as exc:   # no session: valid, kept as the candidate, never sent
            self.setpoints_ignored += 1
            self._report_refused("setpoint_ignored", client, exc.reason, str(exc))
            return
        except SetpointRejected as exc:   # px4_link's own checks (geofence, step rate)
            self.setpoints_rejected += 1
            self._remember(client, None, now, str(exc))
            self._report_refused("setpoint_rejected", client, exc.reason, f"setpoint refused: {exc}")
            return
        # Only setpoints PX4 accepted keep the failsafe away: a stream of garbage is no link.
        self.last_setpoint_at = now

    @staticmethod
    def _to_setpoint(msg: DroneSetpoint) -> Setpoint:
        yaw = msg.yaw if math.isfinite(msg.yaw) else None
        return (VelocitySetpoint(msg.x, msg.y, msg.z, yaw) if msg.is_velocity
                else PositionSetpoint(msg.x, msg.y, msg.z, yaw))

    def _remember(self, client: str, sp: Setpoint | None, now: float, refused: str) -> None:
        with self._lock:
            if client not in self._candidates and len(self._candidates) >= self.MAX_CANDIDATES:
                oldest = min(self._candidates, key=lambda c: self._candidates[c].at)
                del self._candidates[oldest]
            self._candidates[client] = Candidate(sp, now, refused)
        if (not refused and self.config.resume_on_setpoints and client == self.control.holder
                and self.lifecycle.state is OffboardState.FAILSAFE_HOLD and now - self._resume_tried > 3.0):
            self._resume_tried = now   # one attempt at a time, not one per setpoint
            self._commands.submit(self._guarded, "resume", lambda: self._offboard_start(client))

    def _motion(self) -> VehicleMotion | None:
        pos = self.link.telemetry.latest(LocalPosition)
        if pos is None or time.monotonic() - pos.received_at > 1.0:
            return None
        return VehicleMotion((pos.x, pos.y, pos.z), (pos.vx, pos.vy, pos.vz))

    def _watchdog(self) -> None:
        now = time.monotonic()
        if self.lifecycle.state is OffboardState.ACTIVE and now - self.last_setpoint_at > self.config.setpoint_deadline:
            self._on_deadline_missed(None)
        gone = self.control.expire(now)
        if gone:
            self._event("control_changed", f"{gone} released: liveliness lost", "no GCS in control", gone)
        if not self.lifecycle.in_session and self.link.mode == "OFFBOARD" and self.link.connected \
                and now - self._park_sent > 2.0:
            # Real PX4 returns to OFFBOARD after landing and auto-disarm: never leave it there.
            self._park_sent = now
            self._commands.submit(self._guarded, "park", self._park)
        wrong = self.lifecycle.audit()
        if wrong:
            self._event("lifecycle", wrong, "stream stopped")
        self._check_sensor_rate(now)

    def _park(self) -> None:
        if self.lifecycle.park("PX4 in OFFBOARD outside a session"):
            self._event("stray_offboard", "PX4 in OFFBOARD without an operator-requested session", SAFE_MODE)

    def _on_deadline_missed(self, status: Any) -> None:
        with self._lock:   # the event and the watchdog may race on a multi-threaded executor
            if self.lifecycle.state is not OffboardState.ACTIVE or self.failsafe:
                return
            self.failsafe = f"no setpoint for {self.config.setpoint_deadline:.1f} s"
        self._event("setpoint_deadline_missed", self.failsafe, "HOLD", self.control.holder)
        self._commands.submit(self._hold_for_failsafe, self.failsafe)

    def _hold_for_failsafe(self, why: str) -> None:
        try:
            self.lifecycle.deadline_missed(why)   # HOLD first, then stop streaming
        except CommandError as exc:
            log.error("failsafe HOLD failed: %s", exc)
            self._event("failsafe_failed", str(exc), "")

    def _on_params_changed(self, changes: dict[str, Any]) -> None:   # the parameter service's thread
        old, self.config = self.config, self.params.config
        if "control_lease_s" in changes:
            self.control.lease_s = self.config.control_lease_s
        if "report_interval_s" in changes:
            self._limiter.interval_s = self.config.report_interval_s
        if "sensor_rate_hz" in changes and changes["sensor_rate_hz"] != self.sensor_rate_requested:
            self.sensor_rate_requested = self.config.sensor_rate_hz
            self._rate_since = time.monotonic()   # the delivered rate settles again before any warning
            self._commands.submit(self._guarded, "sensor rate", self.request_rates)   # waits for an ACK
        for name, value in changes.items():
            if self._limiter.hit("param_changed", name):
                self._event("param_changed", f"{name}: {getattr(old, name)!r} -> {value!r}", "applied")

    def _on_link_event(self, name: str, details: dict[str, Any]) -> None:   # px4_link's thread: never block
        if name == "offboard_lost":
            new = str(details.get("new_mode", "?"))
            self._event("offboard_lost", f"PX4 left OFFBOARD for {new} by itself", "stream stopped",
                        self.control.holder)
            self._commands.submit(self._guarded, "offboard_lost", lambda: self.lifecycle.px4_left_offboard(new))
        elif name == "armed_changed" and not details.get("armed", True):
            self._commands.submit(self._guarded, "disarmed", self.lifecycle.disarmed)
        elif name == "connected" and not details.get("reconnect"):
            # PX4 came up after the companion: px4_link re-asks only after a *re*connect, so ask now.
            self._rate_since = time.monotonic()
            self._commands.submit(self._guarded, "sensor rate", self.request_rates)
            self._commands.submit(self._guarded, "px4 streams", self.request_streams)
        elif (name == "connected" and details.get("reconnect")) or name == "rebooted":
            self._rate_since = time.monotonic()   # px4_link asks PX4 for the intervals again
            streams = f", {self.px4_streams} streams" if self.streams_asked else ""
            self._event("px4_reconnected", f"PX4 {'rebooted' if name == 'rebooted' else 'heartbeats back'}: "
                        f"sensor rate{' and streams' if streams else ''} asked again",
                        f"HIGHRES_IMU {self.sensor_rate_requested:g} Hz{streams}")
        elif name == "disconnected":
            self._event("px4_disconnected", f"no PX4 heartbeat for {details.get('silent_s', 0):.1f} s", "")

    def request_rates(self) -> None:
        # px4_link remembers the interval and asks again after a PX4 reconnect or reboot.
        self.link.telemetry.request_message_interval("HIGHRES_IMU", self.sensor_rate_requested)

    @staticmethod
    def _streams_in_force(config: CompanionConfig) -> str:
        if config.px4_streams not in PX4_STREAMS:
            raise ValueError(f"px4_streams {config.px4_streams!r}: one of {', '.join(PX4_STREAMS)}")
        if config.mavlink_tunnel and config.px4_streams != "default":
            log.info("px4_streams %s not applied: the MAVLink tunnel's QGC reads PX4's default streams",
                     config.px4_streams)
            return "default"
        return config.px4_streams

    def request_streams(self) -> None:
        """Ask PX4 for the lean streams (nothing with px4_streams default); a refusal or silence
        is logged once per stream and the stream stays at PX4's rate."""
        if not self.streams_asked:
            return
        refused = ask_streams(self.link, self.streams_asked)
        for name, why in refused.items():
            if name not in self.streams_refused:
                log.warning("PX4 stream %s at %g Hz: %s; PX4's own rate applies", name,
                            self.streams_asked[name], why)
            self.streams_refused[name] = why
        if not refused:
            log.info("PX4 streams asked (%s): %s", self.px4_streams,
                     ", ".join(f"{n} {hz:g} Hz" if hz > 0 else f"{n} off" for n, hz in self.streams_asked.items()))

    def sensor_rate_hz(self) -> float:
        """HIGHRES_IMU rate PX4 really delivers (NaN for the first window after start or a reconnect)."""
        if time.monotonic() - self._rate_since < 2.0:
            return math.nan
        return self.link.telemetry.rate_hz("HIGHRES_IMU")

    def _check_sensor_rate(self, now: float) -> None:
        rate = self.sensor_rate_hz()
        want = self.sensor_rate_requested
        if math.isnan(rate) or not self.link.connected or rate >= self.config.sensor_rate_tolerance * want:
            return
        if now - self._sensor_low_warned >= 60.0:
            self._sensor_low_warned = now
            self._event("sensor_rate_low", f"PX4 delivers HIGHRES_IMU at {rate:.0f} Hz, {want:g} Hz requested", "")

    def _guarded(self, what: str, fn: Callable[[], Any]) -> None:
        try:
            fn()
        except (CommandError, Refused, SetpointRejected, RuntimeError) as exc:
            log.error("%s: %s", what, exc)
            self._event("failsafe_failed" if what in ("park", "offboard_lost") else "lifecycle",
                        f"{what} failed: {exc}", "")

    def _on_token(self, sample: Any) -> None:   # Zenoh thread
        client = str(sample.key_expr).rsplit("/", 1)[-1]
        if valid_client_id(client):
            self.control.token(client, sample.kind == zenoh.SampleKind.PUT)

    # -- commands ------------------------------------------------------------------------
    def _on_command(self, cmd: Command) -> CommandResult:
        who = cmd.client_id if valid_client_id(cmd.client_id) else f"<invalid {cmd.client_id[:64]!r}>"
        log.info("command %s (value=%g text=%r force=%s) from %s", cmd.name[:32], cmd.value, cmd.text[:32],
                 cmd.force, who)
        res = self._decide(cmd)
        if not res.success:
            log.warning("command %s from %s refused or failed: %s", cmd.name[:32], who, res.message)
        return res

    def _refuse(self, cmd: Command, why: str) -> CommandResult:
        self.commands_refused += 1
        return CommandResult(False, why, self.link.state.mode)

    def _decide(self, cmd: Command) -> CommandResult:
        if cmd.name not in COMMANDS:
            return self._refuse(cmd, f"unknown command {cmd.name[:32]!r}; commands: {', '.join(COMMANDS)}")
        client = cmd.client_id
        if cmd.name == "release_control":
            if self.control.release(client):
                self._event("control_changed", f"{client} released control", "no GCS in control", client)
                return CommandResult(True, "control released", self.link.state.mode)
            return self._refuse(cmd, f"release_control refused: {client or '<none>'} does not hold control "
                                     f"(holder: {self.control.holder or 'none'})")
        ok, why, previous = self.control.admit(client, cmd.name, claim=True,
                                               force=cmd.force and cmd.name == "take_control")
        if not ok:
            self._report_refused("control_refused", client if valid_client_id(client) else "", cmd.name,
                                 f"command {cmd.name} from {client or '<no id>'}: {why}")
            return self._refuse(cmd, why)
        if previous:
            self._event("control_lost", f"{client} took control from {previous}", "", previous)
        if cmd.name == "take_control":
            return CommandResult(True, f"{client} in control" + (f" (taken from {previous})" if previous else ""),
                                 self.link.state.mode)
        why = self._policy(cmd)
        if why:
            return self._refuse(cmd, why)
        fn = self._handler(cmd)
        future = self._commands.submit(fn)
        try:
            msg = future.result(timeout=20.0)
        except (CommandError, Refused, SetpointRejected) as exc:
            return CommandResult(False, str(exc), self.link.state.mode)
        except Exception as exc:  # noqa: BLE001  (a bad argument, a link that is down: the sender hears it)
            return CommandResult(False, f"{type(exc).__name__}: {exc}", self.link.state.mode)
        return CommandResult(True, msg or "done", self.link.state.mode)

    def _policy(self, cmd: Command) -> str:
        """Why ``cmd`` is not allowed whoever sends it, or ""."""
        if cmd.name == "takeoff" and not (0.5 <= (cmd.value or 5.0) <= 120):
            return f"takeoff altitude {cmd.value} m outside 0.5..120"
        if cmd.name == "disarm" and cmd.force and not self.link.state.landed and not self.config.allow_force_disarm:
            return ("forced disarm refused: the vehicle is not landed (motors would stop in flight); "
                    "the companion allows it only with --allow-force-disarm")
        if cmd.name == "set_param":
            if cmd.text not in self.config.param_allow:
                return (f"set_param {cmd.text[:32]!r} refused: not in the companion's allow-list "
                        f"({', '.join(self.config.param_allow) or 'empty'})")
            if not math.isfinite(cmd.value):
                return f"set_param {cmd.text}: value {cmd.value} is not finite"
        return ""

    def _handler(self, cmd: Command) -> Callable[[], str | None]:
        lc, link, who = self.lifecycle, self.link, cmd.client_id

        def leave(mode: str) -> Callable[[], None]:
            return lambda: self._leave(mode, f"{cmd.name} by {who}")

        def disarm() -> None:
            link.action.disarm(force=cmd.force)
            lc.disarmed()

        def takeoff() -> None:
            if lc.in_session:
                lc.leave(SAFE_MODE, f"takeoff by {who}")
            link.action.takeoff(cmd.value or 5.0)

        handlers: dict[str, Callable[[], Any]] = {
            "arm": self._arm,
            "disarm": disarm,
            "takeoff": takeoff,
            "land": leave("AUTO.LAND"),
            "hold": leave("AUTO.LOITER"),
            "rtl": leave("AUTO.RTL"),
            "offboard_stop": leave("AUTO.LOITER"),
            "offboard_start": lambda: self._offboard_start(who),
            "set_param": lambda: link.param.set(cmd.text, cmd.value),
        }
        fn = handlers[cmd.name]

        def run() -> str | None:
            r = fn()
            return r if isinstance(r, str) else None
        return run

    def _leave(self, mode: str, why: str) -> None:
        self.failsafe = ""
        self.lifecycle.leave(mode, why)

    def _arm(self) -> str:
        # Arming must never take off by itself: PX4 sitting in OFFBOARD outside a session
        # (it returns there after landing) goes to Hold first.
        note = ""
        if self.link.mode == "OFFBOARD" and not self.lifecycle.in_session:
            self.lifecycle.park("arm outside an offboard session")
            note = f"PX4 was in OFFBOARD without a session: switched to {SAFE_MODE} before arming"
        self.link.action.arm()
        return note or "armed"

    def _offboard_start(self, client: str) -> str:
        with self._lock:
            cand = self._candidates.get(client)
        now = time.monotonic()
        fresh = cand is not None and now - cand.at <= max(self.config.setpoint_deadline, 0.5)
        if cand is None or not fresh:
            raise Refused("no_setpoints", f"no recent setpoints from {client}: stream setpoints (from the "
                                          "vehicle's position) before asking for OFFBOARD")
        if cand.sp is None:
            raise Refused("setpoints_refused", f"setpoints refused: {cand.refused}")
        try:
            check_against_vehicle(cand.sp, self._motion(), self.config.max_offset_m, self.config.max_speed)
        except Refused as exc:
            raise Refused(exc.reason, f"setpoints refused: {exc}") from None
        self.lifecycle.start(cand.sp)
        self.last_setpoint_at = time.monotonic()
        self.failsafe = ""
        return "OFFBOARD"

    # -- telemetry -------------------------------------------------------------------
    def _on_imu(self, imu: Imu) -> None:    # px4_link's thread: publish is thread safe
        msg = SensorCombined(
            Header.now(frame_id="base_link"), imu.timestamp_us, list(imu.gyro_rad), 0, 0,
            list(imu.accelerometer_m_s2), 0, list(imu.magnetometer_ga), imu.baro_alt_meter,
            imu.baro_temp_celcius)
        try:
            sent = self.sensor_pub.publish(msg)
        except PublisherClosed:   # shutting down: the link's thread outlived the node by a moment
            return
        self.sent["sensor"].record(sent.seq, sent.stamp_ns)

    def _publish_state(self) -> None:
        st = self.link.state
        pos = self.link.telemetry.latest(LocalPosition)
        att = self.link.telemetry.latest(Attitude)
        batt = self.link.telemetry.latest(Battery)
        sent = self.state_pub.publish(VehicleState(
            Header.now(), st.mode, st.armed, bool(st.landed), self.link.connected, self.link.offboard.streaming,
            [pos.x, pos.y, pos.z] if pos else [math.nan] * 3,
            [pos.vx, pos.vy, pos.vz] if pos else [math.nan] * 3,
            [att.roll, att.pitch, att.yaw] if att else [math.nan] * 3,
            batt.remaining_pct / 100.0 if batt else math.nan, batt.voltage_v if batt else math.nan,
            self.failsafe, self.setpoints_rejected, self.lifecycle.state.value, self.control.holder,
            self.sensor_rate_hz(), self.sensor_rate_requested, self.commands_refused))
        self.sent["state"].record(sent.seq, sent.stamp_ns)

    def _camera_loop(self) -> None:
        cfg = self.config
        try:
            source = open_source(cfg.camera or "test", cfg.image_width, cfg.image_height)
        except RuntimeError as exc:
            log.error("camera: %s; no images", exc)
            return
        rate = RateKeeper(cfg.camera_rate_hz)
        try:
            while not self._stop.is_set():
                frame = source.read()
                if frame is None:
                    log.warning("camera: end of stream")
                    return
                self._publish_frame(frame)
                if self.config.camera_rate_hz != cfg.camera_rate_hz:   # a live `param set` (a GCS's downlink)
                    cfg = self.config
                    rate = RateKeeper(cfg.camera_rate_hz)
                rate.wait()
        finally:
            source.close()

    def _publish_frame(self, frame: Any) -> None:
        head = Header.now(frame_id="camera", seq=self._camera_seq)
        self._camera_seq += 1
        if isinstance(self.image_pub, ImagePublisher):
            self.image_pub.publish(frame, head)
            n = self.image_pub.frames - 1
            self.sent["image"].record(n, head.stamp)   # slices carry the frame number
            for i in range(self.image_pub.last_count):
                self.sent["image_strip"].record(n * MAX_SLICES + i, head.stamp)
            return
        if isinstance(self.image_pub, FecImagePublisher):
            n = self.image_pub.publish(frame, head)
            self.sent["image"].record(n, head.stamp)
            self.sent["image_strip"].record(n * MAX_SLICES, head.stamp)
            return
        if self.config.profile.image_mode == "jpeg":
            h, w = frame.shape[:2]
            img = Image(head, h, w, "jpeg", 0, 0, encode_strip(frame, self.config.profile.jpeg_quality))
        else:
            img = Image.from_array(frame, header=head)
        sent = self.image_pub.publish(img)
        self.sent["image"].record(sent.seq, sent.stamp_ns)

    def close(self) -> None:
        # Runs before the node's publishers go: the link's thread must stop using them first.
        if self.link_monitor is not None:
            self.link_monitor.close()
        self.link.telemetry.remove_listener(self._on_imu)
        self._stop.set()
        if self._camera_thread is not None:
            self._camera_thread.join(timeout=2.0)
        self._commands.shutdown(wait=False, cancel_futures=True)
        try:
            self._tokens.undeclare()
        except zenoh.ZError as exc:   # the session may already be closing
            log.debug("liveliness subscriber: %s", exc)

    def summary(self) -> dict[str, Any]:
        s = self.setpoints.summary().as_dict()
        s["lost_pct"] = self.setpoints.lost_pct()
        return {"setpoints": s, "setpoints_rejected": self.setpoints_rejected,
                "setpoints_ignored": self.setpoints_ignored, "commands_refused": self.commands_refused,
                "control": vars(self.control.counters), "sensor_rate_hz": self.sensor_rate_hz(),
                "offboard_state": self.lifecycle.state.value, "events": self.events_sent,
                "final_mode": self.link.state.mode,
                "px4_streams": {"in_force": self.px4_streams, "asked_hz": self.streams_asked,
                                "refused": self.streams_refused,
                                "delivered_hz": {n: self.link.telemetry.rate_hz(n) for n in SUMMARY_STREAMS}},
                "px4": {"ever_connected": self.link.system_id is not None, "connected": self.link.connected},
                "parameters": {"changed": self.params.changed, "refused": self.params.refused},
                "logs": {"sent": {k: v.to_dict() for k, v in self.sent.items()},
                         "received": {"setpoint": self.setpoints.to_dict()}}}
