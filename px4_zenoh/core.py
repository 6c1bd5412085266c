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

``encoder()``/``send_message()`` are MAVLink's: they raise here (no plugin of this backend calls them).
"""
from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any, TypeVar

import zenoh

from px4_link.commands import CommandAck, CommandSender, NotConnected, command_name
from px4_link.plugin import Event, EventCallback, Listener, MessageHandler, ModeHook, PeriodicHook
from px4_link.ratelimit import RateLimitedLog
from px4_link.telemetry import ExtendedSysState, LocalPosition, Px4State, is_finite_sample
from zenoh_robot.wire.ros2 import pack_attachment

from . import convert
from . import topics as tp
from .inbox import Inbox, TopicQueue
from .uorb import UorbCodec

log = logging.getLogger("px4_zenoh")
T = TypeVar("T")

COUNTERS = ("samples_received", "samples_decoded", "samples_dropped", "samples_skipped", "decode_errors",
            "wrong_key_samples", "hash_mismatches", "messages_sent", "bytes_sent", "setpoints_sent",
            "setpoints_rejected", "setpoints_clamped", "setpoints_expired", "setpoints_unsent",
            "commands_sent", "command_retries", "unsolicited_acks", "duplicate_acks", "reconnects",
            "disconnects", "reboots", "callback_errors", "nonfinite_telemetry", "params_refused",
            "heartbeats_received", "interval_rerequests")
INBOUND = tuple(t for t in tp.USED if t.direction == tp.OUT)
OUTBOUND = tuple(t for t in tp.USED if t.direction == tp.IN)


class ZenohCore:
    """Implements ``px4_link.plugin.Core`` on a Zenoh session that reaches PX4."""

    def __init__(self, session: zenoh.Session, types: dict[str, type[Any]], *, domain: int = 0,
                 heartbeat_timeout: float = 3.0, tick_hz: float = 20.0, source_system: int = 245,
                 source_component: int = 191, target_system: int = 1, target_component: int = 1,
                 command_timeout: float = 1.0, command_retries: int = 3, queue_depth: int = 8) -> None:
        self.session = session
        self.domain = domain
        self.heartbeat_timeout = heartbeat_timeout
        self.tick_hz = tick_hz
        self.source_system, self.source_component = source_system, source_component
        self.target_system, self.target_component = target_system, target_component
        self.rlog = RateLimitedLog(log, burst=1, interval=5.0)
        self.codecs = {t.name: UorbCodec.of(types[t.type_short]) for t in tp.USED}
        self.types = types
        self.keys = tp.KeyBook(domain, {c.type_name: c.type_hash for c in self.codecs.values()})
        self.inbox = Inbox([t.name for t in INBOUND], queue_depth)

        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._state = Px4State()
        self._stats: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self._ever_connected = False
        self._last_px4_time_us = 0
        self.px4_tokens: set[str] = set()
        self.offboard_signal_lost: bool | None = None   # failsafe_flags.offboard_control_signal_lost
        self.latest_status: Any = None

        self._event_listeners: list[EventCallback] = []
        self._latest: dict[type, Any] = {}
        self._listeners: list[tuple[type | None, Listener]] = []
        self._listeners_lock = threading.Lock()
        self._handlers: dict[str, list[MessageHandler]] = {}
        self._mode_hooks: list[ModeHook] = []
        self._periodic: list[PeriodicHook] = []

        self._pubs: dict[str, tuple[str, Any, bytes]] = {}   # topic -> (key, publisher, gid)
        self._seq: dict[str, int] = {}
        self._send_lock = threading.Lock()
        self._entities: list[Any] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._commands = CommandSender(self._send_vehicle_command, command_timeout, command_retries,
                                       double_acked=frozenset())

    # ----------------------------------------------------------------- hooks
    def add_message_handler(self, mtype: str | None, handler: MessageHandler) -> None:
        """``handler(msg)`` on the worker for each decoded sample of topic ``mtype`` (``/fmu/out/...``)."""
        self._handlers.setdefault(mtype or "*", []).append(handler)

    def add_mode_hook(self, hook: ModeHook) -> None:
        self._mode_hooks.append(hook)

    def add_periodic(self, hook: PeriodicHook) -> None:
        self._periodic.append(hook)

    # ----------------------------------------------------------------- lifecycle
    def start(self) -> None:
        if self._threads:
            return
        self._stop.clear()
        liveliness = self.session.liveliness()
        patterns = {tp.token_pattern(self.domain), tp.token_pattern(0)}   # PX4's node token is in domain 0
        for pattern in sorted(patterns):
            self._entities.append(liveliness.declare_subscriber(pattern, self._on_token, history=True))
        for topic in INBOUND:
            q = self.inbox.queues[topic.name]
            self._entities.append(self.session.declare_subscriber(
                topic.any_hash_key(self.domain), self._receiver(topic, q)))
        self._threads = [threading.Thread(target=self._rx_loop, name="px4zenoh-rx", daemon=True),
                         threading.Thread(target=self._tx_loop, name="px4zenoh-tx", daemon=True)]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        self.inbox.wake()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
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
                self._disconnect("PX4's Zenoh tokens are gone")
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
        if not is_finite_sample(sample):
            self.count("nonfinite_telemetry")
            return
        self._latest[type(sample)] = sample
        self.notify()
        for kind, cb in list(self._listeners):
            if kind is None or isinstance(sample, kind):
                self.safe_call(cb, sample)

    def _on_status(self, m: Any) -> None:
        now = time.monotonic()
        mode, armed = convert.mode_of(int(m.nav_state)), int(m.arming_state) == convert.ARMING_STATE_ARMED
        sysid, compid = int(m.system_id) or self.target_system, int(m.component_id) or self.target_component
        events: list[Event] = []
        with self._cond:
            old = self._state
            self._stats["heartbeats_received"] += 1
            self.latest_status = m
            rebooted = 0 < int(m.timestamp) + 250_000 < self._last_px4_time_us
            self._last_px4_time_us = int(m.timestamp)
            self._state = replace(old, connected=True, system_id=sysid, component_id=compid, mode=mode,
                                  custom_mode=int(m.nav_state), armed=armed, last_heartbeat=now,
                                  heartbeats=old.heartbeats + 1)
            if not old.connected:
                reconnect = self._ever_connected
                if reconnect:
                    self._stats["reconnects"] += 1
                self._ever_connected = True
                events.append(("connected", {"system_id": sysid, "component_id": compid, "reconnect": reconnect}))
            if old.mode != mode and old.heartbeats:
                events.append(("mode_changed", {"old": old.mode, "new": mode}))
                for hook in self._mode_hooks:
                    events.extend(hook(old.mode, mode))
            if old.armed != armed and old.heartbeats:
                events.append(("armed_changed", {"armed": armed}))
            if rebooted:
                self._stats["reboots"] += 1
                events.append(("rebooted", {"system_id": sysid}))
            self._cond.notify_all()
        for name, details in events:
            self.emit(name, details)

    def _on_landed(self, landed_state: int) -> None:
        self._publish(ExtendedSysState(landed_state, 0, system_id=self._state.system_id or 0))
        with self._cond:
            old = self._state.landed_state
            if old == landed_state:
                return
            self._state = replace(self._state, landed_state=landed_state)
            self._cond.notify_all()
        self.emit("landed_changed", {"old": old, "new": landed_state, "name": self._state.landed_state_name})

    def _on_ack(self, m: Any) -> None:
        if int(m.target_system) != self.source_system or int(m.target_component) not in (0, self.source_component):
            self.count("unsolicited_acks")   # PX4's own (command 211 after boot) or another client's
            return
        outcome = self._commands.handle_ack(int(m.command), int(m.result), int(m.result_param1),
                                            int(m.result_param2))
        if outcome in ("duplicate", "unsolicited"):
            self.count(f"{outcome}_acks")

    def _disconnect(self, why: str) -> None:
        with self._cond:
            s = self._state
            if not s.connected:
                return
            self._state = replace(s, connected=False)
            self._stats["disconnects"] += 1
            self._cond.notify_all()
        silent = time.monotonic() - (s.last_heartbeat or time.monotonic())
        self.emit("disconnected", {"system_id": s.system_id, "silent_s": silent, "why": why})

    # ----------------------------------------------------------------- the send thread
    def _tx_loop(self) -> None:
        period = 1.0 / self.tick_hz
        next_tick = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                last = self._state.last_heartbeat
                if self._state.connected and last is not None and now - last > self.heartbeat_timeout:
                    self._disconnect(f"no vehicle_status for {now - last:.1f} s")
                for hook in self._periodic:
                    hook()
            except Exception:   # the stream must survive anything
                self.rlog.exception("tx", "px4_zenoh stream thread error")
            next_tick += period
            if next_tick < now:
                next_tick = now + period
            self._stop.wait(max(0.0, next_tick - time.monotonic()))

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

    def send_command(self, command: int, *params: float, timeout: float | None = None,
                     retries: int | None = None) -> CommandAck:
        if not self._state.connected:
            raise NotConnected(command, None, f"{command_name(command)}: no vehicle connected")
        return self._commands.run(command, params, timeout=timeout, retries=retries)

    def cancel_command(self, owner: int, why: str) -> bool:
        return self._commands.cancel(owner, why)

    def encoder(self) -> Any:
        raise RuntimeError("PX4 over Zenoh has no MAVLink encoder: publish uORB messages (ZenohCore.publish)")

    def send_message(self, msg: Any) -> None:
        raise RuntimeError("PX4 over Zenoh sends no MAVLink messages: publish uORB messages (ZenohCore.publish)")

    def vehicle_ids(self) -> tuple[int, int]:
        s = self._state
        return (s.system_id or self.target_system, s.component_id or self.target_component)

    # ----------------------------------------------------------------- state
    @property
    def connected(self) -> bool:
        return self._state.connected

    @property
    def state(self) -> Px4State:
        return self._state

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

    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.1))
        return True

    def notify(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._stats[key] = self._stats.get(key, 0) + n

    def emit(self, name: str, details: dict[str, Any]) -> None:
        log.debug("px4_zenoh event %s %s", name, details)
        for cb in list(self._event_listeners):
            self.safe_call(cb, name, details)

    def add_event_listener(self, callback: EventCallback) -> None:
        with self._lock:
            self._event_listeners.append(callback)

    def safe_call(self, cb: Callable[..., Any], *args: Any) -> None:
        try:
            cb(*args)
        except Exception:
            self.count("callback_errors")
            self.rlog.exception(f"cb{id(cb) % 64}", "px4_zenoh callback %r raised", cb)

    # ----------------------------------------------------------------- the telemetry cache
    def latest(self, kind: type[T]) -> T | None:
        sample: T | None = self._latest.get(kind)
        return sample

    def wait_sample(self, kind: type[T], timeout: float,
                    predicate: Callable[[T], bool] | None = None) -> T | None:
        since = time.monotonic()

        def fresh() -> bool:
            v = self._latest.get(kind)
            return v is not None and v.received_at >= since and (predicate is None or predicate(v))

        return self.latest(kind) if self.wait_until(fresh, timeout) else None

    def add_sample_listener(self, callback: Listener, kind: type | None = None) -> Listener:
        with self._listeners_lock:
            self._listeners.append((kind, callback))
        return callback

    def remove_sample_listener(self, callback: Listener) -> None:
        with self._listeners_lock:
            self._listeners = [(k, c) for k, c in self._listeners if c is not callback]

