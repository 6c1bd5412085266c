"""The companion: Zenoh on one side, PX4 over MAVLink on the other.

Setpoints in (``<id>/setpoint``, DroneSetpoint) -> px4_link's offboard stream, but only
inside an operator-requested offboard session (companion/offboard_session.py) and only from the
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

``Companion`` is the wiring: it makes the node's endpoints from the contract's stream table
and hands them to the parts, one job each: the setpoint gate (setpoint_gate.py), the command
desk (command_desk.py), the deadline failsafe (failsafe.py), the telemetry bridge
(telemetry_bridge.py), the camera streamer (camera_streamer.py), the PX4 worker
(px4_worker.py) and the event reporter (events.py). What is left here: the 20 Hz watchdog
that checks the invariants, px4_link's events, live parameter changes, and the summary.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from drone_contract.commands import COMMAND_SERVICE
from drone_contract.link_protection import RefusalWatch, link_refusals
from drone_contract.messages import CONTROL_TOKEN_PREFIX, Command, CommandResult, valid_client_id
from drone_contract.streams import DOWN, UP, message_of, wired
from px4_link.telemetry import LocalPosition
from px4_link.vehicle import VehicleLink
from zenoh_robot import Node
from zenoh_robot.events import DuplicateNodeInfo, SubscriptionEventCallbacks
from zenoh_robot.loss_feedback import LossMonitor
from zenoh_robot.ros2 import Ros2TypeError
from zenoh_robot.tools.stream_metrics import StreamRecorder
from zenoh_robot.topic_statistics import with_cpu_budget

from .camera_streamer import CameraStreamer
from .command_desk import CommandDesk
from .config import CompanionConfig
from .control import ControlArbiter
from .events import EventReporter
from .failsafe import DeadlineFailsafe
from .flight_actions import FlightActions
from .offboard_session import SAFE_MODE, OffboardLifecycle, OffboardState
from .params import CompanionParameters
from .px4_worker import Px4Worker
from .setpoint_gate import SetpointGate
from .shedding import CameraShedding
from .telemetry_bridge import TelemetryBridge

log = logging.getLogger("companion")

# Executor % of one core the setpoint subscription may take (`zenoh-robot stats`, issue #18): 10 Hz
# of setpoints with their copies measured 0.4 % (median, quiet host; max 0.7): 1.5 leaves room for
# a loaded host and still flags a slow callback or a flood.
SETPOINT_CPU_BUDGET_PCT = 1.5
WATCHDOG_PERIOD_S = 0.05


def flight_actions(node: Node, desk: CommandDesk, link: VehicleLink) -> FlightActions | None:
    """The drone's actions, when the ``ros2`` extra (their types) is installed; else said once."""
    try:
        return FlightActions(node, desk, link)
    except ImportError as exc:
        log.warning("the drone's actions (takeoff, goto, land) are off: their ROS 2 types need the ros2 extra "
                    "(%s); the command service works as ever", exc)
    except Ros2TypeError as exc:   # never fails with the shipped .action files; the companion flies without
        log.error("the drone's actions (takeoff, goto, land) are off: %s; the command service works as ever", exc)
    return None


class Companion:
    def __init__(self, node: Node, link: VehicleLink, config: CompanionConfig) -> None:
        # First: every setting below is read from the parameters in force (-p wins over the flag).
        self.params = CompanionParameters(config)
        config = self.params.declare(node)
        self.node, self.link, self.config = node, link, config
        q = config.profile.qos
        live = self._live_config
        # image_strip: every strip (FEC: every frame) sent, as frame * MAX_SLICES + index, for the
        # experiment's fresh-strip fraction.
        self.sent = {name: StreamRecorder() for name in ("sensor", "state", "image", "image_strip")}
        self._park_sent = 0.0

        events = wired("events", DOWN)
        self.events = EventReporter(node.create_publisher(message_of(events), events.name, q[events.name]),
                                    config.report_interval_s)
        self.link_refusals = RefusalWatch(node.wire, config.report_interval_s)   # sealed links: an attack shows
        self.worker = Px4Worker(self.events, link.cancel_command)
        self.control = ControlArbiter(config.control_lease_s)
        self.lifecycle = OffboardLifecycle(link, self._on_transition)
        self.failsafe = DeadlineFailsafe(self.lifecycle, self.control, self.events, self.worker,
                                         lambda: self.config.setpoint_deadline, self._vehicle_position)
        self.gate = SetpointGate(link, self.control, self.lifecycle, self.failsafe, self.events, self.worker, live)
        link.offboard.geofence = config.geofence()   # px4_link fences every target with the values in force
        self.desk = CommandDesk(link, self.control, self.lifecycle, self.gate, self.failsafe, self.events,
                                self.worker, live)

        sensor, state = wired("sensor", DOWN), wired("state", DOWN)
        self.telemetry = TelemetryBridge(
            link, node.create_publisher(message_of(sensor), sensor.name, q[sensor.name]),
            node.create_publisher(message_of(state), state.name, q[state.name]),
            self.sent["sensor"], self.sent["state"], self.events, self.worker, live)
        image = wired("image", DOWN)
        self.camera = (CameraStreamer(node, image.name, q[image.name], live, self.sent["image"],
                                      self.sent["image_strip"]) if config.camera else None)
        camera = self.camera
        self.shedding = (CameraShedding(lambda: camera.frames_sent, lambda: self.config.camera_rate_hz, self.events)
                         if camera is not None else None)
        # Loss feedback (loss_feedback.py): image parity follows the loss the GCS measures.
        self.loss_monitor = LossMonitor(node, "drone") if config.profile.loss_feedback else None
        set_image_loss = self.camera.set_loss() if self.camera is not None else None
        if self.loss_monitor is not None and set_image_loss is not None:
            self.loss_monitor.adapt(set_image_loss)
        setpoint = wired("setpoint", UP)
        self.setpoint_sub = node.create_subscription(
            message_of(setpoint), setpoint.name, self.gate.on_setpoint,
            q[setpoint.name].replace(deadline=config.setpoint_deadline),
            event_callbacks=SubscriptionEventCallbacks(deadline=self.failsafe.on_deadline_missed),
            topic_statistics=with_cpu_budget(node.enable_topic_statistics, SETPOINT_CPU_BUDGET_PCT))
        self.setpoint_sub.superseded = self.gate.on_superseded   # latest wins: still recorded as arrived
        command_srv = node.create_service(COMMAND_SERVICE, Command, CommandResult, self.desk.on_command)
        self.actions = flight_actions(node, self.desk, link)   # takeoff, goto, land as ROS 2 actions
        if self.loss_monitor is not None:   # reply copies sized from the measured loss (services/service.py)
            self.loss_monitor.adapt(command_srv.set_loss)
        node.create_timer(1.0 / config.state_rate_hz, self._publish_state)
        # The QoS deadline event is the trigger; this watchdog is its backstop, checked at 20 Hz,
        # so the failsafe never depends on one mechanism alone. It also checks the invariants.
        node.create_timer(WATCHDOG_PERIOD_S, self._watchdog)
        self._tokens = node.watch_liveliness(f"{CONTROL_TOKEN_PREFIX}/*", self._on_token)
        presence = wired("presence", UP)   # the holder's lease, where its token cannot reach (multicast)
        node.create_subscription(message_of(presence), presence.name,
                                 lambda msg: self.control.seen(msg.client_id), q[presence.name])
        self.telemetry.start()
        link.add_event_listener(self._on_link_event)
        if self.camera is not None:
            self.camera.start()
        self.params.on_change = self._on_params_changed
        self.params.guard_writes(node, self.control, self.events)   # safety limits: only the GCS in control
        # A second companion with this id that got past the start-up check (zenoh_robot.claim): both say so,
        # and the later start stops (``on_yield``, the CLI's stop) instead of flying beside the other.
        self.yielded = ""
        self.on_yield: Callable[[], None] | None = None
        node.claim.on_duplicate(self._on_duplicate)
        node.add_on_close(self.close)

    def _vehicle_position(self) -> tuple[float, float, float] | None:
        pos = self.link.telemetry.latest(LocalPosition)
        if pos is None or time.monotonic() - pos.received_at > 1.0:
            return None
        return pos.x, pos.y, pos.z

    def _live_config(self) -> CompanionConfig:
        return self.config   # replaced as a whole by a `param set`: the parts read it through this

    def _on_transition(self, old: OffboardState, new: OffboardState, why: str) -> None:
        self.events.event("lifecycle", f"{old.value} -> {new.value}: {why}", new.value)

    def _publish_state(self) -> None:
        self.telemetry.publish_state(self.failsafe.reason, self.gate.rejected, self.lifecycle.state.value,
                                     self.control.holder, self.desk.refused, self.link_refusals.total())

    def _watchdog(self) -> None:
        now = time.monotonic()
        self.failsafe.check(now)
        self.worker.expire(now)   # commands past their reply's deadline never run later
        self.desk.watch_control(now)
        self._park_if_stray(now)
        wrong = self.lifecycle.audit()
        if wrong:
            self.events.event("lifecycle", wrong, "stream stopped")
        self.telemetry.check_sensor_rate(now)
        self._report_link_refusals(now)
        if self.shedding is not None:
            self.shedding.check(now)

    def _report_link_refusals(self, now: float) -> None:
        new = self.link_refusals.poll(now)
        if new:
            n = sum(new.values())
            why = ", ".join(f"{k} {v}" for k, v in sorted(new.items(), key=lambda kv: -kv[1]))
            self.events.event("link_refused", f"refused {n} sealed sample(s) or call(s) on the link ({why}): "
                              "forged, replayed or recorded before a restart", "refused", count=n)

    def _stray_offboard(self) -> bool:
        return not self.lifecycle.in_session and self.link.offboard.stray() and self.link.connected

    def _park_if_stray(self, now: float) -> None:
        # Real PX4 returns to OFFBOARD after landing and auto-disarm: never leave it there.
        if self._stray_offboard() and now - self._park_sent > 2.0:
            self._park_sent = now
            self.worker.submit_guarded("park", self._park)

    def settle(self, timeout: float = 2.0) -> None:
        """Before the summary at exit: PX4 back in OFFBOARD after landing (it restores the mode it
        had) is parked now if the watchdog has not, and the summary waits, at most ``timeout``, for
        PX4's heartbeat (1 Hz) to show it, so the final mode reported is the one the vehicle is in."""
        if not self._stray_offboard():
            return
        now = time.monotonic()
        self._park_if_stray(now)
        end = now + timeout
        while self.link.offboard.stray() and time.monotonic() < end:
            time.sleep(0.05)

    def _park(self) -> None:
        mode = self.link.offboard.session_mode
        if self.lifecycle.park(f"PX4 in {mode} outside a session"):
            self.events.event("stray_offboard", f"PX4 in {mode} without an operator-requested session", SAFE_MODE)

    def _on_params_changed(self, changes: dict[str, Any]) -> None:   # the parameter service's thread
        self.config = self.params.config
        if "control_lease_s" in changes:
            self.control.lease_s = self.config.control_lease_s
        if "report_interval_s" in changes:
            self.events.limiter.interval = self.config.report_interval_s
        if "sensor_rate_hz" in changes:
            self.telemetry.set_sensor_rate(self.config.sensor_rate_hz)
        if changes.keys() & {"fence_radius_m", "fence_ceiling_m", "fence_floor_m"}:
            self.link.offboard.geofence = self.config.geofence()

    def _on_link_event(self, name: str, details: dict[str, Any]) -> None:   # px4_link's thread: never block
        if name == "offboard_lost":
            new = str(details.get("new_mode", "?"))
            self.events.event("offboard_lost", f"PX4 left OFFBOARD for {new} by itself", "stream stopped",
                              self.control.holder)
            self.worker.submit_guarded("offboard_lost", lambda: self.lifecycle.px4_left_offboard(new))
        elif name == "armed_changed" and not details.get("armed", True):
            self.worker.submit_guarded("disarmed", self.lifecycle.disarmed)
        else:
            self.telemetry.on_link_event(name, details)

    def _on_duplicate(self, info: DuplicateNodeInfo) -> None:   # the node's executor
        action = "resolved" if not info.alive else "stopping" if info.yields else "keeps running"
        self.events.event("duplicate_id", info.describe(), action)
        if info.alive and info.yields and not self.yielded:
            self.yielded = info.describe()
            if self.on_yield is not None:
                self.on_yield()

    def _on_token(self, key: str, alive: bool) -> None:   # the node's executor
        client = key.rsplit("/", 1)[-1]
        if valid_client_id(client):
            self.control.token(client, alive)

    def close(self) -> None:
        # Runs before the node's publishers go: the link's thread must stop using them first.
        if self.loss_monitor is not None:
            self.loss_monitor.close()
        self.telemetry.close()
        if self.camera is not None:
            self.camera.close()
        if self.actions is not None:
            self.actions.close()
        self.worker.shutdown()
        self._tokens.undeclare()

    def summary(self) -> dict[str, Any]:
        received = self.gate.received
        s = received.summary().as_dict()
        s["lost_pct"] = received.lost_pct()
        return {"setpoints": s, "setpoints_rejected": self.gate.rejected,
                "setpoints_ignored": self.gate.ignored, "commands_refused": self.desk.refused,
                "control": vars(self.control.counters), "sensor_rate_hz": self.telemetry.sensor_rate_hz(),
                "offboard_state": self.lifecycle.state.value, "events": self.events.sent,
                "final_mode": self.link.state.mode,
                "px4_streams": self.telemetry.summary(),
                "px4": {"ever_connected": self.link.system_id is not None, "connected": self.link.connected,
                        **self.link.backend_summary()},
                "parameters": {"changed": self.params.changed, "refused": self.params.refused},
                "failsafe": self.failsafe.summary(), "px4_worker": self.worker.summary(),
                "repeater": self.node.repeater_stats(),
                "link_refused": link_refusals(self.node.wire),
                "shed": ({**self.shedding.summary(), "camera_nice": self.camera.nice}
                         if self.shedding is not None and self.camera is not None else {}),
                "logs": {"sent": {k: v.to_dict() for k, v in self.sent.items()},
                         "received": {"setpoint": received.to_dict()}}}
