"""The GCS node: streams setpoints to each drone, listens to its telemetry, images and events.

One ``Gcs`` holds one Node (one Zenoh session) and a ``DroneView`` per drone. Drones
are given (``--drones uav1,uav2``) or discovered from the ``*/state`` topics they
publish (gcs/discovery.py). Everything a dashboard or a summary shows is read from ``DroneView``.

Identity: every setpoint and command carries this GCS's ``client_id`` (``user@host`` by
default), and the session declares the liveliness token ``zr_gcs/<client_id>`` by which
a drone's companion knows its controller is still there (companion/control.py).

Setpoints go only to a drone this GCS may steer: one whose state names this GCS as its controller,
or no controller (the first claim: PX4 needs setpoints before ``offboard_start``); never one another
GCS controls, so an observer never fills a gap in control.

Targets start where the drone is and a pattern is flown from that anchor, or from the
drone's formation slot (gcs/planner.py: each ``DroneView`` has its ``TargetPlanner``, fed
with the drone's reported position). Swarms (gcs/formation.py): with a formation (``line``,
``grid``; the CLI's ``auto`` picks ``line`` for several drones) each drone has its own slot,
taken in join order, and all fly the ``Gcs``'s one formation clock. A drone may fly its own
pattern (``GcsConfig.patterns``).

Receive path: telemetry callbacks only record; image pieces are filed, not decoded, on the
executor (the library's image receiver, ``zenoh_robot.image``), so many camera streams cannot
starve setpoints and sensors.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drone_contract.commands import COMMAND_SERVICE
from drone_contract.messages import (
    CONTROL_TOKEN_PREFIX,
    FAILSAFE_KINDS,
    Command,
    CommandResult,
    DroneSetpoint,
    FailsafeEvent,
    GcsPresence,
    VehicleState,
)
from drone_contract.streams import DOWN, UP, message_of, wired
from zenoh_robot import Node
from zenoh_robot.image import FrameRecords, image_receiver
from zenoh_robot.loss_feedback import LossMonitor, apply_repeat_plan
from zenoh_robot.msgs import Header, SensorCombined
from zenoh_robot.services import ServiceCallError, command_retry
from zenoh_robot.tools.stream_metrics import StreamRecorder
from zenoh_robot.topic_statistics import with_cpu_budget

from .alerts import Alerts
from .config import GcsConfig
from .decimation import SensorDecimation
from .discovery import watch_drones
from .downlink import DownlinkRates
from .formation import slot
from .patterns import PathPoint, make_pattern
from .planner import FormationClock, Position, TargetPlanner
from .shedding import PERIOD_S as SHEDDING_PERIOD_S
from .shedding import SheddingWatch
from .vehicle_identity import StateSource, watch_claims

log = logging.getLogger("gcs")
# Executor time (% of one core) each drone stream may take before `zenoh-robot stats` shows it red
# and the log warns (TopicStatisticsOptions.cpu_budget_pct). The whole GCS costs ~2-3.5 % of a core
# per drone with the swarm downlink (docs/swarm.md). busy_pct measured (1 drone, FEC camera, quiet
# host, medians of 40 windows x 3 runs): at 50 Hz / 15 fps sensor 0.6-0.7, image 0.5-0.6, state 0.1;
# at the drone's own 200 Hz / 30 fps sensor 1.6, image 1.1. The budgets leave ~3x for a loaded host
# and sum to 4.5, under the 5 % per drone of issue #18: a stream over its budget is worth a look.
STREAM_CPU_BUDGET_PCT = {"sensor": 2.0, "state": 0.5, "image": 2.0}
# The presence this GCS sends each drone it controls: well inside the companion's control lease (5 s by
# default, never under its 1 s setpoint deadline), so a GCS that no longer streams (waiting for a landing)
# keeps control where its liveliness token does not reach the drone (UDP multicast carries none).
PRESENCE_PERIOD_S = 0.5
ATTACK_SHOWN_S = 30.0   # a drone's rising refusal count keeps it marked under attack this long
MAX_SEEN = 1000         # drone ids remembered as heard (bounded: a peer chooses them)


@dataclass
class ImageStats:
    frames: int = 0
    complete: int = 0
    last_age_ms: float = float("nan")


class DroneView:
    """Everything the GCS sends to and knows about one drone."""

    MAX_EVENTS = 20

    def __init__(self, gcs: Gcs, drone_id: str, index: int = 0) -> None:
        self.id = drone_id
        self.gcs = gcs
        node, cfg = gcs.node, gcs.config
        self.index = index
        self.slot = slot(index, cfg.formation, cfg.spacing)
        self.pattern_name = cfg.patterns.get(drone_id, cfg.pattern)
        self.plan = TargetPlanner(self.pattern_name, altitude=cfg.altitude, size=cfg.size, speed=cfg.speed,
                                  rate_hz=cfg.rate_hz, formation=cfg.formation, slot=self.slot,
                                  formation_clock=gcs.formation_clock, fly=cfg.auto_fly)
        q = cfg.profile.qos
        self.setpoints_sent = 0
        self.state: VehicleState | None = None
        self.state_at = 0.0
        self.refusals_at = -math.inf
        self.events: list[FailsafeEvent] = []
        self.failures: list[str] = []     # failsafes and refusals addressed to this GCS (bounded)
        self.events_seen = 0
        self.alerts = Alerts(drone_id)    # a second companion with this id, a matched stream that sends nothing
        self.source = StateSource(lambda why: self.alerts.raise_("duplicate_id", why))
        # image: frames shown (sliced: begun, possibly with stale strips); image_whole: frames whose every
        # strip is fresh; image_strip: fresh strips (FEC: whole frames), as frame * MAX_SLICES + index.
        self.streams = {name: StreamRecorder() for name in ("sensor", "state", "image", "image_whole", "image_strip")}
        self.sent = {"setpoint": StreamRecorder()}
        ns = f"/{drone_id}"
        # Names and types from the contract's stream table (drone_contract.streams): the companion
        # wires the other end from the same rows, and tests/wing/test_contract.py checks both are there.
        setpoint = wired("setpoint", UP)
        self.setpoint_pub = node.create_publisher(message_of(setpoint), f"{ns}/{setpoint.name}", q[setpoint.name])
        budget = {k: with_cpu_budget(node.enable_topic_statistics, v) for k, v in STREAM_CPU_BUDGET_PCT.items()}
        sensor, state, events = wired("sensor", DOWN), wired("state", DOWN), wired("events", DOWN)
        silent = self.alerts.silence_events      # "uav3 sensor: publisher seen, 0 samples in 5 s" (alerts.py)
        # What this GCS's own queues drop, named (shedding.py); the sensor then asked for less (decimation.py).
        self.decimation = SensorDecimation(drone_id)
        self.shedding = SheddingWatch(self.alerts, lambda stream, w: self.decimation.on_window(self, stream, w))
        self.shedding.watch("sensor", node.create_subscription(
            message_of(sensor), f"{ns}/{sensor.name}", self._on_sensor, q[sensor.name],
            topic_statistics=budget["sensor"], event_callbacks=silent("sensor")))
        node.create_subscription(message_of(state), f"{ns}/{state.name}", self._on_state, q[state.name],
                                 topic_statistics=budget["state"], event_callbacks=silent("state"))
        node.create_subscription(message_of(events), f"{ns}/{events.name}", self._on_event, q[events.name])
        image = wired("image", DOWN)
        # Filed on the executor, decoded only when a frame is looked at (latest_frame); the records
        # number what arrived as the companion numbers what it sent (the experiment pairs them).
        records = FrameRecords(frame=self.streams["image"].record, whole=self.streams["image_whole"].record,
                               piece=self.streams["image_strip"].record)
        self.frames = image_receiver(cfg.profile.image_mode, node, f"{ns}/{image.name}", q[image.name],
                                     records=records, topic_statistics=budget["image"])
        self.shedding.watch("image", getattr(self.frames, "subscription", None))
        # Retried with one request id until the deadline; the companion runs each call once
        # (zenoh_robot/services/idempotency.py).
        self.commands = node.create_client(f"{ns}/{COMMAND_SERVICE}", Command, CommandResult, retry=command_retry(node))
        presence = wired("presence", UP)
        self.presence_pub = node.create_publisher(message_of(presence), f"{ns}/{presence.name}", q[presence.name])

    # -- telemetry -------------------------------------------------------------------
    def _on_sensor(self, msg: SensorCombined, info: Any) -> None:
        self.streams["sensor"].record(info.seq, info.source_stamp_ns, info.received_stamp_ns)

    def _on_state(self, msg: VehicleState, info: Any) -> None:
        if not self.source.accept(info.publisher_id, time.monotonic()):
            return     # another vehicle with this id: never merged into this one's view (vehicle_identity.py)
        self.streams["state"].record(info.seq, info.source_stamp_ns, info.received_stamp_ns)
        previous_at = self.state_at
        if self.state is not None and msg.link_refused > self.state.link_refused:
            self.refusals_at = time.monotonic()     # the drone is refusing sealed samples now: shown (dashboard)
        self.state, self.state_at = msg, time.monotonic()
        if self.gcs.downlink is not None:   # a join (or rejoin): ask for this GCS's downlink rates
            self.gcs.downlink.on_state(self.id, previous_at, self.state_at, float(msg.sensor_rate_requested_hz),
                                       msg.controller)
        self.plan.track(msg.position, msg.in_session_mode)

    def lost_pct(self, stream: str) -> float:
        """Share of ``stream`` that never arrived (NaN before there is anything to say). Strips are numbered
        frame * MAX_SLICES + index (FEC: one per frame), so their sequence numbers leave gaps no strip fills:
        theirs is the image receiver's count of strips expected against strips that arrived."""
        if stream == "image_strip":
            k = self.frames
            return 100.0 * (1 - k.strips_fresh / k.strips_expected) if k.strips_expected else float("nan")
        return self.streams[stream].lost_pct()

    @property
    def under_attack(self) -> bool:
        """The drone refused sealed samples or calls (forged, replayed, recorded before a restart) within
        the last ``ATTACK_SHOWN_S``: what its state's ``link_refused`` total says, as it rises."""
        return time.monotonic() - self.refusals_at < ATTACK_SHOWN_S

    @property
    def in_control(self) -> bool:
        return self.state is not None and self.state.controller == self.gcs.config.client_id

    @property
    def may_stream(self) -> bool:
        """This GCS holds control of the drone, or nobody does (it may be about to claim it)."""
        s = self.state
        return s is not None and s.controller in ("", self.gcs.config.client_id)

    @property
    def session_active(self) -> bool:
        s = self.state
        return s is not None and s.offboard_state == "active" and self.in_control

    def _on_event(self, msg: FailsafeEvent) -> None:
        self.events.append(msg)
        del self.events[:-self.MAX_EVENTS]   # bounded
        self.events_seen += 1
        me = self.gcs.config.client_id
        for_me = msg.client_id in ("", me)
        if (msg.kind in FAILSAFE_KINDS and for_me) or (msg.kind == "setpoint_rejected" and msg.client_id == me):
            self.failures.append(f"{msg.kind}: {msg.detail}")
            del self.failures[:-self.MAX_EVENTS]
        if msg.kind in ("lifecycle", "setpoint_ignored"):
            log.info("%s: %s (%s)", self.id, msg.kind, msg.detail)
        else:
            log.warning("%s: %s (%s) -> %s", self.id, msg.kind, msg.detail, msg.action or "no action")

    @property
    def image(self) -> ImageStats:
        """The image figures the dashboard and the summary show (the receiver's counters; nothing decoded)."""
        k = self.frames
        return ImageStats(k.frames, k.complete, k.last_age_ms)

    @property
    def latest_frame(self) -> np.ndarray | None:
        """The newest frame, decoded now on the caller's thread (not the executor's)."""
        got = self.frames.latest()
        return None if got is None else got[0]

    # -- targets (gcs/planner.py) -----------------------------------------------------
    def _position(self) -> Position | None:
        s = self.state
        if s is None or not s.connected or not all(math.isfinite(v) for v in s.position):
            return None
        x, y, z = (float(v) for v in s.position)
        return x, y, z

    def target(self) -> PathPoint | None:
        """What to stream now, or None (no position known: nothing safe to send)."""
        return self.plan.target(self._position(), self.session_active)

    def freeze(self) -> None:
        """Keep sending the current target (a jump back to the start would be refused)."""
        self.plan.freeze(self._position(), self.session_active)

    @property
    def fly(self) -> bool:
        """The pattern is flown once the session is active (else the drone holds where it began)."""
        return self.plan.fly

    # -- commands --------------------------------------------------------------------
    def command(self, name: str, value: float = 0.0, text: str = "", force: bool = False,
                timeout: float = 8.0) -> CommandResult:
        """Send a command and wait for the drone's answer; errors come back as a failed result.

        A drone whose state arrives before its command service is known (a lossy link: its streams
        may cross before its declarations) is waited for within ``timeout`` before the one call: a
        second call would be a new command that could run twice."""
        request = Command(name, float(value), text, force, self.gcs.config.client_id)
        end = time.monotonic() + timeout
        client = self.commands
        if client.discovers_servers and not client.service_is_ready():
            client.wait_for_service(0.8 * timeout)   # the call itself keeps the rest of the timeout
        try:
            return client.call(request, timeout=max(0.5, end - time.monotonic()))
        except ServiceCallError as exc:
            return CommandResult(False, f"{type(exc).__name__}: {exc}", "")

    def send_setpoint(self, t: PathPoint) -> None:
        sent = self.setpoint_pub.publish(DroneSetpoint(Header.now(seq=self.setpoints_sent), self.gcs.config.client_id,
                                                       t.x, t.y, t.z, t.yaw, False))
        self.sent["setpoint"].record(sent.seq, sent.stamp_ns)
        self.setpoints_sent += 1

    def send_presence(self) -> None:
        self.presence_pub.publish(GcsPresence(Header.now(), self.gcs.config.client_id))

    @property
    def link_age(self) -> float:
        return time.monotonic() - self.state_at if self.state_at else float("inf")


class Gcs:
    def __init__(self, node: Node, config: GcsConfig) -> None:
        self.node = node
        self.config = config
        self.drones: dict[str, DroneView] = {}
        self._lock = threading.Lock()
        self.pattern = make_pattern(config.pattern, config.altitude, config.size, config.speed)
        for name in config.patterns.values():
            make_pattern(name)   # an unknown name fails here, not at the first setpoint
        slot(0, config.formation, config.spacing)
        self.formation_clock = FormationClock()
        self.streaming = True
        self._declare_parameters()
        rates = {k: v for k, v in (("sensor_rate_hz", config.sensor_rate_hz),
                                   ("camera_rate_hz", config.camera_rate_hz)) if v is not None}
        on = rates or config.decimate_sensor
        self.downlink = DownlinkRates(node, rates, self._downlink_refused, config.client_id) if on else None
        if self.downlink is not None:
            node.add_on_close(self.downlink.close)
        # The companion knows its controller is alive by this token (dropped when the session ends).
        self._token = node.declare_liveliness_token(f"{CONTROL_TOKEN_PREFIX}/{config.client_id}")
        for d in config.drones:
            self.add_drone(d)
        # Every drone heard, asked for or not: a mission for a drone that is not there names the ones that are.
        self._seen: set[str] = set()
        self._seen_lock = threading.Lock()     # added on Zenoh's thread, read by the mission's
        self._discovery = watch_drones(node, self._on_drone_heard)
        self._claims = watch_claims(node, self._on_companion_claims)
        node.create_timer(1.0 / config.rate_hz, self._stream)
        node.create_timer(PRESENCE_PERIOD_S, self._presence)
        node.create_timer(SHEDDING_PERIOD_S, self._check_shedding)
        # Loss feedback (loss_feedback.py): setpoint copies follow the loss the drones measure.
        self.loss_monitor = LossMonitor(node, "gcs") if config.profile.loss_feedback else None
        if self.loss_monitor is not None:
            self.loss_monitor.adapt(self._adapt_copies)
            node.add_on_close(self.loss_monitor.close)
        self._saver: threading.Thread | None = None
        self.saved_images: dict[str, Path] = {}
        if config.save_image:
            node.create_timer(config.save_every, self._save_images)

    def _downlink_refused(self, drone_id: str, why: str) -> None:
        d = self.drones.get(drone_id)
        if d is not None:   # shown on the dashboard's row like a refused setpoint
            d.failures.append(why)
            del d.failures[:-d.MAX_EVENTS]

    def _adapt_copies(self, _worst: float) -> None:
        # Per drone, from that drone's own probes (their origin is its id; the worst link until it is
        # heard), not the adapter's worst of all: one drone in a fade must not raise every drone's copies
        # on a shared radio channel. Never NaN here: the monitor adapts only once a peer is heard.
        # Fades: copies sized for the loss that follows a loss too (loss_feedback.BurstEstimate).
        monitor = self.loss_monitor
        if monitor is None:
            return
        for drone_id, d in list(self.drones.items()):
            loss = monitor.outgoing_loss(drone_id)
            d.commands.set_loss(loss)    # command retries and reply copies sized from it (services/retry.py)
            if d.setpoint_pub.qos.repeat and d.setpoint_pub.qos.deadline:
                apply_repeat_plan(d.setpoint_pub, loss, monitor.burst(drone_id), 1.0 / self.config.rate_hz)

    def _declare_parameters(self) -> None:
        """What this GCS runs with, for `zenoh-robot param list /gcs` (read-only: set at start)."""
        for name, value, what in self.config.parameters():
            if not self.node.has_parameter(name):
                self.node.declare_parameter(name, value, what, read_only=True)

    def _on_drone_heard(self, drone_id: str) -> None:   # Zenoh thread: hand over to the executor
        with self._seen_lock:
            if drone_id not in self._seen and len(self._seen) < MAX_SEEN:
                self._seen.add(drone_id)
        if drone_id not in self.drones and not self.config.drones:
            def add() -> None:
                self.add_drone(drone_id)
            self.node.executor.call_soon(add)

    def _on_companion_claims(self, drone_id: str, zids: list[str]) -> None:   # the executor
        d = self.drones.get(drone_id)
        if len(zids) > 1:
            why = f"{len(zids)} companions claim this id (zids {', '.join(zids)}): the later start must stop"
            if d is not None:
                d.alerts.raise_("duplicate_claim", why)
            else:
                log.warning("%s: %s", drone_id, why)
        elif d is not None:
            d.alerts.clear("duplicate_claim", "one companion claims this id again")

    def seen(self) -> list[str]:
        """Every drone id heard on the network (asked for or not), sorted."""
        with self._seen_lock:
            return sorted(self._seen)

    def add_drone(self, drone_id: str) -> DroneView:
        with self._lock:
            if drone_id not in self.drones:
                log.info("drone %s joined", drone_id)
                self.drones[drone_id] = DroneView(self, drone_id, index=len(self.drones))
            return self.drones[drone_id]

    def take_control(self) -> dict[str, CommandResult]:
        """Explicit takeover (``--take-control``): the previous GCS is told by the drone."""
        return {d.id: d.command("take_control", force=True) for d in list(self.drones.values())}

    def release_control(self, timeout: float = 5.0) -> dict[str, CommandResult]:
        """On exit: give control back at once instead of leaving it to the liveliness lease. A drone
        in an offboard session holds (AUTO.LOITER) before it is released (companion/command_desk.py),
        which waits for PX4: the drones are asked at once, each on its own thread."""
        results: dict[str, CommandResult] = {}
        if self.downlink is not None:
            self.downlink.restore()     # while still in control: the companion takes rates from its controller only

        def release(d: DroneView) -> None:
            results[d.id] = res = d.command("release_control", timeout=timeout)
            log.info("%s: release_control: %s", d.id, res.message)

        threads = [threading.Thread(target=release, args=(d,), name=f"release-{d.id}", daemon=True)
                   for d in list(self.drones.values()) if d.in_control]
        for th in threads:
            th.start()
        for th in threads:
            th.join(timeout + 1.0)
        return results

    def _stream(self) -> None:
        if not self.streaming:
            return
        for drone in list(self.drones.values()):
            t = drone.target()
            if t is not None and drone.may_stream:
                drone.send_setpoint(t)

    def _check_shedding(self) -> None:
        for d in list(self.drones.values()):
            d.shedding.check()

    def _presence(self) -> None:
        # Even while streaming stops (landing, paused): the lease is the holder's as long as this GCS runs.
        for drone in list(self.drones.values()):
            if drone.in_control:
                drone.send_presence()

    def image_path(self, drone_id: str) -> Path:
        """--save-image FILE: FILE itself for one drone given, FILE_<id> otherwise (told once, in the log)."""
        assert self.config.save_image is not None
        path = self.config.save_image
        if len(self.config.drones) == 1 and drone_id == self.config.drones[0]:
            return path
        return path.with_name(f"{path.stem}_{drone_id}{path.suffix}")

    def _save_images(self) -> None:
        # Decoding runs here, on its own thread: the executor is never held up by it.
        if self._saver is None or not self._saver.is_alive():
            self._saver = threading.Thread(target=self._save_now, name="gcs-save-image", daemon=True)
            self._saver.start()

    def _save_now(self) -> None:
        from PIL import Image as PILImage
        for drone in list(self.drones.values()):
            arr = drone.latest_frame
            if arr is None:
                continue
            path = self.image_path(drone.id)
            try:
                PILImage.fromarray(arr).save(path)
            except (OSError, ValueError) as exc:
                log.warning("%s: cannot save its frame to %s: %s", drone.id, path, exc)
                continue
            if drone.id not in self.saved_images:
                self.saved_images[drone.id] = path
                log.warning("%s: frames saved to %s every %g s", drone.id, path, self.config.save_every)
