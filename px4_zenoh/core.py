"""ZenohCore: px4_link's ``plugin.Core`` over PX4's own Zenoh module, so px4_link's Action (and the
offboard plugin's checks) run unchanged on it.

- Keys come from PX4's liveliness tokens (``topics.KeyBook``); a hash mismatch is logged by name,
  counted, and that topic is refused (its samples dropped, nothing published on it).
- Receiving: one data subscriber per used ``/fmu/out`` topic (hash chunk ``*``: a sample on a key
  other than the one PX4 announced is counted and dropped). Zenoh's thread hands the bytes to
  ``inbox.Inbox`` (bounded, drop-oldest per topic); the ``px4zenoh-rx`` worker decodes and updates the
  state and the telemetry cache, and calls listeners and hooks (px4_link's receive-thread contract).
- The vehicle: ``vehicle_status`` is the heartbeat (mode from nav_state, armed from arming_state, ids,
  pre-arm verdict); ``vehicle_land_detected`` the landed state; PX4's node token going away (or
  ``heartbeat_timeout`` without vehicle_status) a disconnect.
- Commands: ``send_command`` publishes a ``vehicle_command`` (timestamp 0: PX4 stamps it; from_external)
  through px4_link's CommandSender, and a ``vehicle_command_ack`` answers it only when its command AND
  its target ids (= our source ids) match: PX4's stray ACKs after boot (command 211, arbitrary targets)
  never do. PX4 ACKs each command once over uORB (no MAVLink double ACK).
- The ``px4zenoh-tx`` thread ticks at ``tick_hz``: the watchdog, then the periodic hooks (the
  offboard stream).
- The state, counters, events, telemetry cache, listeners and the threads' lifecycle are
  ``px4_link.vehicle_core.VehicleCore``'s, shared with px4_link's MAVLink core.

``encoder()``/``send_message()`` are MAVLink's: they raise here (no plugin of this backend calls them).
"""
from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from px4_link.commands import CommandSender, NotConnected, command_name
from px4_link.plugin import Event, MessageHandler
from px4_link.telemetry import ExtendedSysState, LocalPosition, is_finite_sample
from px4_link.vehicle_core import VehicleCore
from zenoh_robot.wire.ros2 import pack_attachment

from . import convert
from . import topics as tp
from .inbox import Inbox, TopicQueue
from .uorb import UorbCodec

log = logging.getLogger("px4_zenoh")

# setpoints_withheld: asked while an external mode (external_mode.offboard) is not active, so not sent
COUNTERS = ("samples_received", "samples_decoded", "samples_dropped", "samples_skipped", "decode_errors",
            "wrong_key_samples", "hash_mismatches", "messages_sent", "bytes_sent", "setpoints_sent",
            "setpoints_rejected", "setpoints_clamped", "setpoints_expired", "setpoints_unsent", "setpoints_withheld",
            "commands_sent", "command_retries", "unsolicited_acks", "duplicate_acks", "reconnects",
            "disconnects", "reboots", "callback_errors", "nonfinite_telemetry", "params_refused",
            "heartbeats_received", "interval_rerequests")
INBOUND = tuple(t for t in tp.USED if t.direction == tp.OUT)
OUTBOUND = tuple(t for t in tp.USED if t.direction == tp.IN)


class ZenohCore(VehicleCore):
    """Implements ``px4_link.plugin.Core`` on a Zenoh session that reaches PX4."""

    def __init__(self, session: zenoh.Session, types: dict[str, type[Any]], *, domain: int = 0,
                 heartbeat_timeout: float = 3.0, tick_hz: float = 20.0, source_system: int = 245,
                 source_component: int = 191, target_system: int = 1, target_component: int = 1,
                 command_timeout: float = 1.0, command_retries: int = 3, queue_depth: int = 8) -> None:
        super().__init__(log=log, tag="px4_zenoh", thread_prefix="px4zenoh", counters=COUNTERS,
                         heartbeat_timeout=heartbeat_timeout, tick_hz=tick_hz, source_system=source_system,
                         source_component=source_component)
        self.session = session
        self.domain = domain
        self.target_system, self.target_component = target_system, target_component
        self.codecs = {t.name: UorbCodec.of(types[t.type_short]) for t in tp.USED}
        self.types = types
        self.keys = tp.KeyBook(domain, {c.type_name: c.type_hash for c in self.codecs.values()})
        self.inbox = Inbox([t.name for t in INBOUND], queue_depth)

        self._last_px4_time_us = 0
        self.px4_tokens: set[str] = set()
        self.offboard_signal_lost: bool | None = None   # failsafe_flags.offboard_control_signal_lost
        self.latest_status: Any = None

        self._handlers: dict[str, list[MessageHandler]] = {}

        self._pubs: dict[str, tuple[str, Any, bytes]] = {}   # topic -> (key, publisher, gid)
        self._seq: dict[str, int] = {}
        self._send_lock = threading.Lock()
        self._entities: list[Any] = []
        self._commands = CommandSender(self._send_vehicle_command, command_timeout, command_retries,
                                       double_acked=frozenset())

    # ----------------------------------------------------------------- hooks
    def add_message_handler(self, mtype: str | None, handler: MessageHandler) -> None:
        """``handler(msg)`` on the worker for each decoded sample of topic ``mtype`` (``/fmu/out/...``)."""
        self._handlers.setdefault(mtype or "*", []).append(handler)

    # ----------------------------------------------------------------- lifecycle
    def _open(self) -> None:
        liveliness = self.session.liveliness()
        patterns = {tp.token_pattern(self.domain), tp.token_pattern(0)}   # PX4's node token is in domain 0
        for pattern in sorted(patterns):
            self._entities.append(liveliness.declare_subscriber(pattern, self._on_token, history=True))
        for topic in INBOUND:
            q = self.inbox.queues[topic.name]
            self._entities.append(self.session.declare_subscriber(
                topic.any_hash_key(self.domain), self._receiver(topic, q)))

    def _wake(self) -> None:
        self.inbox.wake()

    def _close(self) -> None:
        for e in self._entities + [p for _, p, _ in self._pubs.values()]:
            try:
                e.undeclare()
            except Exception:   # noqa: BLE001 - the session may already be closed
                pass
        self._entities, self._pubs = [], {}

    # ----------------------------------------------------------------- Zenoh's threads
    def _receiver(self, topic: tp.Px4Topic, q: TopicQueue) -> Callable[[zenoh.Sample], None]:
        keys, inbox = self.keys, self.inbox

        def on_sample(sample: zenoh.Sample) -> None:
            if not q.offer(time.monotonic()):
                return
            if str(sample.key_expr) != keys.key(topic):   # not PX4's announced key (another hash, no token)
                with self._lock:
                    self._stats["wrong_key_samples"] += 1
                return
            inbox.put(q, sample.payload.to_bytes())
        return on_sample

    def _on_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if "/px4_" not in key:
            return
        if sample.kind == zenoh.SampleKind.DELETE:
            with self._lock:
                self.px4_tokens.discard(key)
                gone = not self.px4_tokens
            if gone:
                self._disconnect(time.monotonic(), "PX4's Zenoh tokens are gone")
            return
        with self._lock:
            self.px4_tokens.add(key)
        mismatch = self.keys.learn(key)
        if mismatch is not None:
            self.count("hash_mismatches")
            log.warning("px4_zenoh: %s; topic %s refused", mismatch, mismatch.topic)
            self.emit("hash_mismatch", {"topic": mismatch.topic, "type": mismatch.type_name,
                                        "theirs": mismatch.theirs, "ours": mismatch.ours, "message": str(mismatch)})

    # ----------------------------------------------------------------- the worker
    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            self.inbox.wait(0.1)
            for name, payload, received_at in self.inbox.drain():
                try:
                    msg = self.codecs[name].decode(payload)
                except Exception as exc:   # noqa: BLE001 - a bad sample is counted, the worker goes on
                    self.count("decode_errors")
                    self.rlog.warning(f"dec{name}", "px4_zenoh: %s: undecodable sample: %s", name, exc)
                    continue
                self.count("samples_decoded")
                try:
                    self._handle(name, msg, received_at)
                except Exception:
                    self.rlog.exception("handle", "px4_zenoh: error handling %s", name)

    def _handle(self, name: str, msg: Any, received_at: float) -> None:
        sysid = self._state.system_id or self.target_system
        if name == tp.VEHICLE_STATUS.name:
            self._on_status(msg)
            self._publish(convert.sys_status(msg, sysid))
        elif name == tp.COMMAND_ACK.name:
            self._on_ack(msg)
        elif name == tp.FAILSAFE_FLAGS.name:
            with self._cond:
                self.offboard_signal_lost = bool(msg.offboard_control_signal_lost)
                self._cond.notify_all()
        elif name == tp.LAND_DETECTED.name:
            self._on_landed(convert.LANDED_ON_GROUND if msg.landed else convert.LANDED_IN_AIR)
        elif name == tp.SENSOR_COMBINED.name:
            self._publish(convert.imu(msg, sysid))
        elif name == tp.ATTITUDE.name:
            self._publish(convert.attitude(msg, sysid))
        elif name == tp.LOCAL_POSITION.name:
            self._publish(convert.local_position(msg, sysid))
        elif name == tp.GLOBAL_POSITION.name:
            self._publish(convert.global_position(msg, self.latest(LocalPosition), sysid))
        elif name == tp.BATTERY.name:
            self._publish(convert.battery(msg, sysid))
        for handler in self._handlers.get(name, []) + self._handlers.get("*", []):
            self.safe_call(handler, msg)

    def _publish(self, sample: Any) -> None:
        """The worker: a converted sample goes to the cache only when finite (px4_link checks before)."""
        if not is_finite_sample(sample):
            self.count("nonfinite_telemetry")
            return
        super()._publish(sample)

    def _on_status(self, m: Any) -> None:
        mode, armed = convert.mode_of(int(m.nav_state)), int(m.arming_state) == convert.ARMING_STATE_ARMED
        sysid, compid = int(m.system_id) or self.target_system, int(m.component_id) or self.target_component

        def check_reboot() -> list[Event]:   # under the state lock: PX4's clock went back
            self.latest_status = m
            rebooted = 0 < int(m.timestamp) + 250_000 < self._last_px4_time_us
            self._last_px4_time_us = int(m.timestamp)
            if not rebooted:
                return []
            self._stats["reboots"] += 1
            return [("rebooted", {"system_id": sysid})]

        self._on_vehicle_heartbeat(sysid, compid, mode, armed,
                                   {"custom_mode": int(m.nav_state), **self._external_fields(int(m.nav_state))},
                                   check_reboot)

    def _on_landed(self, landed_state: int) -> None:
        self._publish(ExtendedSysState(landed_state, 0, system_id=self._state.system_id or 0))
        self._set_landed_state(landed_state)

    def _on_ack(self, m: Any) -> None:
        self._on_command_ack(int(m.target_system), int(m.target_component), int(m.command), int(m.result),
                             int(m.result_param1), int(m.result_param2))

    # ----------------------------------------------------------------- the send thread
    def _tick(self, now: float) -> None:
        self._check_watchdog(now)

    def _silence_reason(self, silent: float) -> str:
        return f"no vehicle_status for {silent:.1f} s"

    # ----------------------------------------------------------------- sending
    def can_publish(self, topic: tp.Px4Topic) -> bool:
        return self.keys.key(topic) is not None

    def publish(self, topic: tp.Px4Topic, msg: Any) -> bool:
        """Encode and put ``msg`` on PX4's key for ``topic``; False (nothing sent) while PX4 has not
        announced that key, or announced it with another hash."""
        key = self.keys.key(topic)
        if key is None:
            return False
        payload = self.codecs[topic.name].encode(msg)
        with self._send_lock:
            entry = self._pubs.get(topic.name)
            if entry is None or entry[0] != key:
                if entry is not None:
                    entry[1].undeclare()
                entry = (key, self.session.declare_publisher(key), hashlib.sha256(key.encode()).digest()[:16])
                self._pubs[topic.name] = entry
                self._seq[topic.name] = 0
            seq = self._seq[topic.name] = self._seq[topic.name] + 1
            # rmw_zenoh's attachment (PX4 ignores it; ROS 2 tools on the same router read it).
            entry[1].put(payload, attachment=pack_attachment(seq, time.time_ns(), entry[2]))
        with self._lock:
            self._stats["messages_sent"] += 1
            self._stats["bytes_sent"] += len(payload)
        return True

    def message(self, topic: tp.Px4Topic, **fields: Any) -> Any:
        return self.types[topic.type_short](**fields)

    def _send_vehicle_command(self, command: int, params: Any, confirmation: int) -> None:
        p = [float(v) for v in params]
        msg = self.message(tp.VEHICLE_COMMAND, timestamp=0, param1=p[0], param2=p[1], param3=p[2], param4=p[3],
                           param5=p[4], param6=p[5], param7=p[6], command=command,
                           target_system=self._state.system_id or self.target_system,
                           target_component=self.target_component, source_system=self.source_system,
                           source_component=self.source_component, confirmation=confirmation & 0xFF,
                           from_external=True)
        if not self.publish(tp.VEHICLE_COMMAND, msg):
            raise NotConnected(command, None, f"{command_name(command)}: PX4 has not announced "
                                              f"{tp.VEHICLE_COMMAND.name} (no token, or a hash mismatch)")

    def encoder(self) -> Any:
        raise RuntimeError("PX4 over Zenoh has no MAVLink encoder: publish uORB messages (ZenohCore.publish)")

    def send_message(self, msg: Any) -> None:
        raise RuntimeError("PX4 over Zenoh sends no MAVLink messages: publish uORB messages (ZenohCore.publish)")

    def vehicle_ids(self) -> tuple[int, int]:
        s = self._state
        return (s.system_id or self.target_system, s.component_id or self.target_component)

    # ----------------------------------------------------------------- state
    @property
    def can_send(self) -> bool:
        return bool(self._threads) and self._state.connected

    def stats(self) -> dict[str, int]:
        with self._lock:
            s = dict(self._stats)
        qs = self.inbox.queues.values()
        s.update(samples_received=sum(q.received for q in qs), samples_dropped=sum(q.dropped for q in qs),
                 samples_skipped=sum(q.skipped for q in qs), commands_sent=self._commands.sent,
                 command_retries=self._commands.retried)
        return s
