"""Per-entity QoS event state: matching, compatibility, deadline, liveliness, message lost.

Peers come from the graph (``on_peer``, Zenoh's thread), time from the node's
QoSMonitor (``tick``, its thread), samples from the executor. Each of these only
updates counters under a lock and hands the status object to the executor, where
the user's callback runs.

Liveliness (ROS 2 semantics): a publisher is alive while its process lives (its
graph token exists) and, when it offers a finite lease, while it asserts within
that lease: AUTOMATIC publishers are asserted by the node's monitor thread,
MANUAL_BY_TOPIC ones by ``publish()`` or ``assert_liveliness()``. Assertions reach
subscriptions as the samples themselves or as heartbeats on ``@zr/alive/<topic>``.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from typing import Any, Protocol

import msgpack

from . import events as ev
from .context import EntityContext
from .graph import ANY_TYPE_HASH, TopicEndpointInfo
from .qos import LivelinessPolicy, QoSProfile
from .qos_compat import check_compatibility
from .silence import SilenceWatch, silence_window

log = logging.getLogger("zenoh_robot.qos_events")

ALIVE_PREFIX = "@zr/alive"
MAX_CLAIMS = 4096    # endpoint claims one entity judges; the graph's own table is the first bound


def heartbeat_key(topic_key: str) -> str:
    return f"{ALIVE_PREFIX}/{topic_key}"


class WatchedEndpoint(Protocol):
    """What the event state reads of its publisher or subscription (public attributes only)."""
    topic: str
    key: str
    qos: QoSProfile
    type_name: str
    type_hash: str

    @property
    def gid(self) -> int: ...


class WatchedPublisher(WatchedEndpoint, Protocol):
    last_publish_mono: float | None


class WatchedSubscription(WatchedEndpoint, Protocol):
    last_sample_mono: float | None

    def redeclare(self) -> bool: ...


class _EntityEvents:
    def __init__(self, context: EntityContext, entity: WatchedEndpoint, callbacks: Any) -> None:
        topic, key, qos = entity.topic, entity.key, entity.qos
        self.context = context
        self._type_name = entity.type_name
        self._type_hash = entity.type_hash
        self.topic = topic
        self.key = key
        self.qos = qos
        self.callbacks = callbacks
        self._lock = threading.Lock()
        self.matched: dict[int, TopicEndpointInfo] = {}
        # Every claim judged once, compatible or not. A claim is a whole token, not its gid: anyone can
        # declare a token carrying another endpoint's gid (it is on the wire), and a gid-keyed table
        # would let a forged incompatible claim, seen first, shadow the real endpoint's.
        self._peers: set[TopicEndpointInfo] = set()
        self.claims_refused = 0            # claims past MAX_CLAIMS: not judged, counted
        self.matched_total = 0
        self.incompatible_total = 0
        self.incompatible_type_total = 0
        self.deadline_total = 0
        self._deadline_ref: float | None = None    # the arrival/publish time the count below refers to
        self._deadline_counted = 0
        self.tick_period = min(p for p in (qos.deadline, qos.liveliness_lease_duration, 1.0) if p is not None)

    def fire(self, name: str, status: Any) -> None:
        cb = getattr(self.callbacks, name, None)
        if cb is None:
            return
        if not self.context.executor.call_soon(lambda: cb(status)):
            log.warning("event %s on %r dropped: executor queue full", name, self.topic)

    def _deadline_missed(self, last: float | None, now: float) -> int:
        """Whole deadline periods since ``last`` not yet counted (each is one miss, as DDS counts)."""
        period = self.qos.deadline
        if period is None or last is None:
            return 0
        if last != self._deadline_ref:
            self._deadline_ref, self._deadline_counted = last, 0
        missed = int((now - last) / period)
        new = missed - self._deadline_counted
        if new <= 0:
            return 0
        self._deadline_counted = missed
        self.deadline_total += new
        return new

    def _match(self, appeared: bool, info: TopicEndpointInfo, offered: QoSProfile, requested: QoSProfile,
               incompatible_cls: type) -> bool | None:
        """Update matching with one claim (token). Appeared: True (its gid newly matched), False
        (incompatible) or None (unchanged); gone: True when it was the claim its gid matched by."""
        if not appeared:
            with self._lock:
                self._peers.discard(info)
                # Only the claim that matched unmatches its gid: another token naming it going away does not.
                gone = self.matched.pop(info.endpoint_gid) if self.matched.get(info.endpoint_gid) == info else None
                current = len(self.matched)
            if gone is None:
                return None
            self.fire("matched", ev.MatchedInfo(self.matched_total, 0, current, -1))
            return True
        with self._lock:    # the graph and a new entity's first look may both report a peer
            if info in self._peers:
                return None
            if len(self._peers) >= MAX_CLAIMS:
                self.claims_refused += 1
                return None
            self._peers.add(info)
        own_type_hash, own_type = self._type_hash, self._type_name
        if info.topic_type_hash != own_type_hash and ANY_TYPE_HASH not in (info.topic_type_hash, own_type_hash):
            with self._lock:
                self.incompatible_type_total += 1
                total = self.incompatible_type_total
            status = ev.IncompatibleTypeInfo(total, 1, info.topic_type)
            if getattr(self.callbacks, "incompatible_type", None) is None:
                log.info("%s on topic %r uses type %s, this one %s: they will not communicate",
                         "publisher" if incompatible_cls is ev.QoSRequestedIncompatibleQoSInfo else "subscription",
                         info.topic_name, info.topic_type, own_type)
            self.fire("incompatible_type", status)
            return None     # not blocked here: its samples are counted and logged as type mismatches
        verdict = check_compatibility(offered, requested)
        if not verdict.compatible:
            with self._lock:
                self.incompatible_total += 1
                total = self.incompatible_total
            status = incompatible_cls(total, 1, verdict.policy, verdict.reason)
            if getattr(self.callbacks, "incompatible_qos", None) is None:
                side = "subscription" if incompatible_cls is ev.QoSOfferedIncompatibleQoSInfo else "publisher"
                log.warning("new %s of node %s%s on topic %r has incompatible QoS (%s): no messages will flow "
                            "between them", side, info.node_namespace.rstrip("/") + "/", info.node_name,
                            info.topic_name, verdict.reason)
            self.fire("incompatible_qos", status)
            return False
        with self._lock:
            if info.endpoint_gid in self.matched:
                return None     # a second compatible claim of a matched gid: nothing new
            self.matched[info.endpoint_gid] = info
            self.matched_total += 1
            total, current = self.matched_total, len(self.matched)
        self.fire("matched", ev.MatchedInfo(total, 1, current, 1))
        return True

    @property
    def current_count(self) -> int:
        with self._lock:
            return len(self.matched)


class PublisherEvents(_EntityEvents):
    """Offered side: matched subscriptions, offered deadline, liveliness lost, AUTOMATIC assertions."""

    def __init__(self, context: EntityContext, pub: WatchedPublisher, callbacks: Any) -> None:
        super().__init__(context, pub, ev.check_callbacks(callbacks, ev.PublisherEventCallbacks))
        self.pub = pub
        self.liveliness_lost_total = 0
        self._asserted_at: float | None = None
        self._alive = False
        self._last_heartbeat = 0.0
        self._lease = pub.qos.liveliness_lease_duration
        self._manual = pub.qos.liveliness is LivelinessPolicy.MANUAL_BY_TOPIC
        self._hb_key = heartbeat_key(pub.key)
        self._hb_payload = msgpack.packb(pub.gid)
        if pub.qos.deadline is not None or self._lease is not None:
            context.qos_monitor.register(self)

    def on_peer(self, appeared: bool, info: TopicEndpointInfo) -> None:
        self._match(appeared, info, self.qos, info.qos_profile, ev.QoSOfferedIncompatibleQoSInfo)

    def assert_liveliness(self) -> None:
        self._asserted_at = time.monotonic()
        self._send_heartbeat(self._asserted_at)

    def _send_heartbeat(self, now: float) -> None:
        self._last_heartbeat = now
        try:
            self.context.session.put(self._hb_key, self._hb_payload)
        except Exception as exc:   # session closing: nothing to assert to
            log.debug("heartbeat not sent: %s", exc)

    def tick(self, now: float) -> None:
        new = self._deadline_missed(self.pub.last_publish_mono, now)
        if new:
            self.fire("deadline", ev.QoSOfferedDeadlineMissedInfo(self.deadline_total, new))
        lease = self._lease
        if lease is None:
            return
        if not self._manual:
            # AUTOMATIC: the node asserts for its publisher; a sample sent recently already did.
            last = max(self.pub.last_publish_mono or 0.0, self._last_heartbeat)
            if now - last >= lease / 3:
                self._send_heartbeat(now)
            return
        asserted = max(self.pub.last_publish_mono or 0.0, self._asserted_at or 0.0)
        if asserted == 0.0:
            return     # never asserted: not yet alive, so nothing to lose
        alive = now - asserted <= lease
        if self._alive and not alive:
            self.liveliness_lost_total += 1
            self.fire("liveliness", ev.QoSLivelinessLostInfo(self.liveliness_lost_total, 1))
        self._alive = alive

    def close(self) -> None:
        self.context.qos_monitor_if_any(lambda m: m.unregister(self))


@dataclass
class _Writer:
    lease: float | None
    manual: bool
    last_seen: float
    alive: bool
    asserted: bool


class SubscriptionEvents(_EntityEvents):
    """Requested side: matched publishers (the rest are blocked), deadline, liveliness, message lost."""

    def __init__(self, context: EntityContext, sub: WatchedSubscription, callbacks: Any) -> None:
        super().__init__(context, sub, ev.check_callbacks(callbacks, ev.SubscriptionEventCallbacks))
        self.sub = sub
        # Lifespan is the publisher's promise (ROS 2); this subscription's own caps it.
        self._own_lifespan_ns = int(sub.qos.lifespan * 1e9) if sub.qos.lifespan else None
        self.blocked: frozenset[int] = frozenset()   # read per sample on the executor: swapped, never mutated
        self._incompatible: dict[int, set[TopicEndpointInfo]] = {}   # gid -> its incompatible claims
        self.message_lost_total = 0
        self._expected_period_s: float | None = None
        self.lifespans_ns: dict[int, int] = {}     # offered lifespan of each matched publisher
        self.alive_count = 0
        self.not_alive_count = 0
        self._writers: dict[int, _Writer] = {}
        self.leased_writers = False     # any matched publisher with a lease: samples then assert it
        self._hb_sub: Any = None
        self._registered = False
        self._matched_at: float | None = None     # when the newest publisher matched (the silence watch)
        self._silence = SilenceWatch(silence_window(None, sub.qos.deadline)) \
            if self.callbacks.silent_stream is not None else None
        if sub.qos.deadline is not None or self._silence is not None:
            self._register()

    @property
    def expected_period_s(self) -> float | None:
        return self._expected_period_s if self._silence is not None else None

    @expected_period_s.setter
    def expected_period_s(self, period: float | None) -> None:
        """The stream's period, where the QoS has no deadline to say it: silence is 5 of them (silence.py)."""
        self._expected_period_s = period
        if self._silence is not None:
            self._silence.window_s = silence_window(period, self.qos.deadline)

    def _register(self) -> None:
        # Again on every new leased writer: the monitor re-reads tick_period, which may have shrunk.
        self._registered = True
        self.context.qos_monitor.register(self)

    # -- graph (Zenoh thread) ---------------------------------------------------------
    def on_peer(self, appeared: bool, info: TopicEndpointInfo) -> None:
        gid = info.endpoint_gid
        result = self._match(appeared, info, info.qos_profile, self.qos, ev.QoSRequestedIncompatibleQoSInfo)
        with self._lock:
            if appeared and result is False:
                self._incompatible.setdefault(gid, set()).add(info)
            elif not appeared and gid in self._incompatible:
                self._incompatible[gid].discard(info)
                if not self._incompatible[gid]:
                    del self._incompatible[gid]
            # Blocked while some claim of the gid is incompatible and none is compatible: a compatible
            # claim (the real endpoint's own token) always wins over a forged one.
            if gid in self._incompatible and gid not in self.matched:
                self.blocked = self.blocked | {gid}
            elif gid in self.blocked:
                self.blocked = self.blocked - {gid}
        if result is False or (not appeared and result is not True):
            return
        if not appeared:
            with self._lock:
                if gid in self.lifespans_ns:
                    self.lifespans_ns = {k: v for k, v in self.lifespans_ns.items() if k != gid}
                writer = self._writers.pop(gid, None)
                if writer is None:
                    return
                if writer.alive:
                    self.alive_count -= 1
                    change = (-1, 0)
                elif writer.asserted:
                    self.not_alive_count -= 1
                    change = (0, -1)
                else:
                    return
            self._fire_liveliness(*change)
            return
        if result is None:
            return
        self._matched_at = time.monotonic()
        q = info.qos_profile
        lease = q.liveliness_lease_duration
        manual = q.liveliness is LivelinessPolicy.MANUAL_BY_TOPIC
        # AUTOMATIC is alive from the moment it is seen; MANUAL_BY_TOPIC once it first asserts.
        alive = not (manual and lease is not None)
        if q.lifespan is not None:
            lifespan_ns = int(q.lifespan * 1e9)
            if self._own_lifespan_ns is not None:
                lifespan_ns = min(lifespan_ns, self._own_lifespan_ns)
            self.lifespans_ns = {**self.lifespans_ns, gid: lifespan_ns}
        with self._lock:
            # last_seen 0: a MANUAL_BY_TOPIC writer has not asserted yet.
            self._writers[gid] = _Writer(lease, manual, time.monotonic() if alive else 0.0, alive, alive)
            if alive:
                self.alive_count += 1
        if lease is not None:
            self.leased_writers = True
            self.tick_period = min(self.tick_period, lease)
            self._ensure_heartbeats()
            self._register()
        if alive:
            self._fire_liveliness(1, 0)

    def _ensure_heartbeats(self) -> None:
        with self._lock:
            if self._hb_sub is not None:
                return
            self._hb_sub = self.context.session.declare_subscriber(heartbeat_key(self.key), self._on_heartbeat)

    def _on_heartbeat(self, sample: Any) -> None:
        try:
            gid = msgpack.unpackb(sample.payload.to_bytes())
        except Exception:
            return
        writer = self._writers.get(gid) if isinstance(gid, int) else None
        if writer is not None:
            writer.last_seen = time.monotonic()

    def _fire_liveliness(self, d_alive: int, d_not_alive: int) -> None:
        with self._lock:
            status = ev.QoSLivelinessChangedInfo(self.alive_count, self.not_alive_count, d_alive, d_not_alive)
        self.fire("liveliness", status)

    # -- executor ---------------------------------------------------------------------
    def on_sample(self, gid: int, now: float) -> None:
        writer = self._writers.get(gid)
        if writer is not None:
            writer.last_seen = now

    def on_lost(self, gap: int) -> None:
        self.message_lost_total += gap
        cb = self.callbacks.message_lost
        if cb is not None:   # already on the executor: call it now, in order with the samples
            try:
                cb(ev.QoSMessageLostInfo(self.message_lost_total, gap))
            except Exception:
                log.exception("message_lost callback on %r raised", self.topic)

    # -- monitor thread ---------------------------------------------------------------
    def tick(self, now: float) -> None:
        new = self._deadline_missed(self.sub.last_sample_mono, now)
        if new:
            self.fire("deadline", ev.QoSRequestedDeadlineMissedInfo(self.deadline_total, new))
        if self._silence is not None:
            silent = self._silence.check(now, self.current_count, self._matched_at, self.sub.last_sample_mono)
            if silent is not None:
                if silent.silent:   # recover where this side can: the subscriber declared again, once an episode
                    silent = replace(silent, redeclared=self.sub.redeclare())
                self.fire("silent_stream", silent)
        changes: list[tuple[int, int]] = []
        with self._lock:
            for w in self._writers.values():
                if w.lease is None:
                    continue
                fresh = now - w.last_seen <= w.lease
                if w.manual and not w.asserted:
                    if w.last_seen > 0 and fresh:
                        w.asserted = w.alive = True
                        self.alive_count += 1
                        changes.append((1, 0))
                    continue
                if w.alive and not fresh:
                    w.alive = False
                    self.alive_count -= 1
                    self.not_alive_count += 1
                    changes.append((-1, 1))
                elif not w.alive and fresh:
                    w.alive = True
                    self.alive_count += 1
                    self.not_alive_count -= 1
                    changes.append((1, -1))
        for d_alive, d_not in changes:
            self._fire_liveliness(d_alive, d_not)

    def close(self) -> None:
        if self._registered:
            self.context.qos_monitor_if_any(lambda m: m.unregister(self))
        if self._hb_sub is not None:
            try:
                self._hb_sub.undeclare()
            except Exception:
                pass
