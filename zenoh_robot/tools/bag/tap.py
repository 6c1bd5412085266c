"""Listen to topics as raw wire bytes, found through the graph as they appear (recorder and bridge).

Each topic is a raw subscription of the node (``create_subscription(None, topic, cb, qos,
raw=True)``): it shows in the graph (``zenoh-robot topic info -a``), matches publishers of
every type, and deduplicates redundant/repeated copies like any subscription; its
callback (on the node's executor, which must be spun) only appends ``(topic, envelope
bytes, envelope header and msgpack fields, receive time)`` to a bounded queue (overflow is
dropped and counted). One worker thread subscribes to newly announced topics and hands each
sample (a :class:`TapSample`) to ``handle``, so disk writes and clients never hold up the
executor. The subscription has already unpacked, checked and deduplicated the envelope: the
worker neither unpacks it again nor keeps its own deduplication. No decoding into message
classes happens here, so any type, known or not, is carried.
"""
from __future__ import annotations

import logging
import re
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from zenoh_robot.graph import EndpointType, TopicEndpointInfo
from zenoh_robot.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from zenoh_robot.qos_compat import Compatibility, check_compatibility

if TYPE_CHECKING:
    from zenoh_robot.node import Node
    from zenoh_robot.subscription import MessageInfo, RawMessage

log = logging.getLogger("zenoh_robot.bag")

MAX_TOPICS = 512                 # a peer inventing topics cannot grow a tap without limit
MAX_QUEUE_BYTES = 64 << 20       # samples waiting for the worker thread
MAX_UNKNOWN_TYPES = 4096         # ROS 2 types remembered as having no definition here


@dataclass(slots=True)
class TapSample:
    """One fresh sample of ``topic``. ``data``: the envelope that brought it, or None when that
    envelope came with the previous sample (one envelope can bring several: recovered ones)."""
    topic: str
    data: bytes | None
    received_ns: int
    type_name: str
    type_hash: str
    publisher_id: int
    seq: int
    stamp_ns: int
    fields: Any                  # the body as msgpack decoded it


@dataclass
class TapCounters:
    received: int = 0            # samples delivered by the subscriptions
    dropped: int = 0             # queue full: the worker (disk, CPU, clients) could not keep up
    handle_errors: int = 0       # samples the worker failed on (counted, never fatal)
    topics_refused: int = 0      # beyond MAX_TOPICS
    topics_excluded: int = 0     # matched ``exclude``
    resubscribed: int = 0        # a publisher our request could not match appeared: asked again
    # the subscriptions' own counts (see Subscription): bytes that were no envelope, queue overflow
    sub_malformed: int = 0
    sub_dropped: int = 0
    sub_lost: int = 0


def reader_qos(publishers: list[TopicEndpointInfo]) -> QoSProfile:
    """A request every publisher serves (as ``ros2 bag`` does): best effort, transient local only
    when all of them keep samples, deep enough for bursts of image slices."""
    keeps = bool(publishers) and all(p.qos_profile.durability is DurabilityPolicy.TRANSIENT_LOCAL
                                     for p in publishers)
    return QoSProfile(ReliabilityPolicy.BEST_EFFORT,
                      DurabilityPolicy.TRANSIENT_LOCAL if keeps else DurabilityPolicy.VOLATILE,
                      HistoryPolicy.KEEP_LAST, 1000)


def normalize_topic(topic: str) -> str:
    return "/" + topic.strip("/")


class Tap:
    """Base: ``start()``, then ``handle(sample)`` on the worker; ``tick()`` every
    ``tick_period`` s there too; ``close()`` drains the queue and calls ``finish()`` on the worker."""

    tick_period = 1.0

    def __init__(self, node: "Node", topics: list[str] | None = None, *,
                 max_queue_bytes: int = MAX_QUEUE_BYTES, name: str = "tap", exclude: str | None = None) -> None:
        self.node = node
        self.all_topics = topics is None
        self.wanted = {normalize_topic(t) for t in topics or []}
        # ros2 bag's --exclude: a regular expression searched in each topic name
        self.exclude = re.compile(exclude) if exclude else None
        self.max_queue_bytes = max_queue_bytes
        self.tap_counters = TapCounters()
        self.subscribed: dict[str, Any] = {}
        self._queue: deque[tuple[TapSample, int]] = deque()    # (sample, bytes it holds)
        self._queue_bytes = 0
        self._pending_topics: deque[str] = deque()
        self._sub_qos: dict[str, QoSProfile] = {}
        self._last_data: dict[str, bytes] = {}
        self._announced: set[str] = set()
        self._no_definition: set[str] = set()     # ROS 2 types with no definition here (MAX_UNKNOWN_TYPES)
        self._cond = threading.Condition()
        self._stop = False
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    # -- lifetime -------------------------------------------------------------------------
    def start(self) -> "Tap":
        self.node.graph.listeners.append(self._on_graph)
        self._thread.start()
        self.node.refresh_graph(1.0)
        for info in self.node.graph.endpoints(kind=EndpointType.PUBLISHER):
            self._on_graph(True, info)
        return self

    def close(self) -> None:
        """Stop listening, handle what is queued, then ``finish()``; idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self.node.graph.listeners.remove(self._on_graph)
        except ValueError:
            pass
        for sub in list(self.subscribed.values()):     # counted before finish() writes the counters
            try:
                self._count_subscription(sub)
                self.node.destroy_subscription(sub)
            except Exception:
                pass
        with self._cond:
            self._stop = True
        with self._cond:
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join()
        else:
            self._drain()
            self.finish()

    def _count_subscription(self, sub: Any) -> None:
        c = self.tap_counters
        c.sub_malformed += sub.counters.malformed
        c.sub_dropped += sub.counters.dropped
        c.sub_lost += sub.counters.lost

    # -- hooks ----------------------------------------------------------------------------
    def handle(self, sample: TapSample) -> None:
        raise NotImplementedError

    def tick(self) -> None:
        pass

    def finish(self) -> None:
        pass

    def ros2_publisher(self, sample: TapSample, counters: Any) -> TopicEndpointInfo | None:
        """The typed ROS 2 publisher of a CDR sample (a raw ROS 2 subscription gets no type name): its own
        token, else one of the topic's publishers. None, counted on ``counters`` (a subclass's, with
        ``untyped`` and ``no_definition``), while the graph has told of none, or for a type found to
        have no definition here (:meth:`no_ros2_definition`)."""
        pubs = [p for p in self.node.graph.endpoints(sample.topic[1:], EndpointType.PUBLISHER) if p.topic_type]
        if not pubs:
            counters.untyped += 1
            return None
        pubs.sort(key=lambda p: p.endpoint_gid != sample.publisher_id)   # its own token first
        if pubs[0].topic_type in self._no_definition:
            counters.no_definition += 1
            return None
        return pubs[0]

    def no_ros2_definition(self, type_name: str, topic: str, counters: Any, what: str) -> None:
        """A ROS 2 type this process has no definition of (its schema cannot be made): counted, named once
        in the log, and its later samples refused early by :meth:`ros2_publisher`."""
        counters.no_definition += 1
        if len(self._no_definition) < MAX_UNKNOWN_TYPES:
            self._no_definition.add(type_name)
            log.warning("no ROS 2 definition of %s here: %s %s", type_name, topic, what)

    # -- discovery (Zenoh's thread: hand on only) ------------------------------------------
    def _on_graph(self, appeared: bool, info: TopicEndpointInfo) -> None:
        if not appeared or info.endpoint_type is not EndpointType.PUBLISHER:
            return
        topic = info.topic_name
        if topic.startswith("/_zr") or (not self.all_topics and topic not in self.wanted):
            return
        with self._cond:
            if topic in self._announced:
                # A publisher our request does not match (a VOLATILE one where we asked for
                # TRANSIENT_LOCAL) would be blocked: ask again with what every publisher serves.
                requested = self._sub_qos.get(topic)
                if requested is not None and check_compatibility(info.qos_profile, requested).compatibility \
                        is Compatibility.ERROR:
                    self._pending_topics.append(topic)
                    self._cond.notify()
                return
            if self.exclude is not None and self.exclude.search(topic):
                if len(self._announced) < MAX_TOPICS:
                    self._announced.add(topic)      # counted once
                self.tap_counters.topics_excluded += 1
                return
            if len(self._announced) >= MAX_TOPICS:
                self.tap_counters.topics_refused += 1
                return
            self._announced.add(topic)
            self._pending_topics.append(topic)
            self._cond.notify()

    def _subscribe(self, topic: str) -> None:
        pubs = self.node.graph.endpoints(topic[1:], EndpointType.PUBLISHER)
        qos = reader_qos(pubs)
        old = self.subscribed.get(topic)
        if old is not None:
            if old.qos == qos:
                return
            self._count_subscription(old)
            self.node.destroy_subscription(old)
            self.tap_counters.resubscribed += 1
        self._sub_qos[topic] = qos
        self.subscribed[topic] = self.node.create_subscription(
            None, topic, lambda raw, info, t=topic: self._on_raw(t, raw, info), qos, raw=True)
        if self._closed:      # close() ran meanwhile and may not have seen this one
            late = self.subscribed.pop(topic, None)
            if late is not None:
                self.node.destroy_subscription(late)
            return
        log.debug("listening to %s", topic)   # one per topic: the summary counts them

    def _on_raw(self, topic: str, raw: "RawMessage", info: "MessageInfo") -> None:
        # The executor: queue and return. One envelope that brings several fresh samples (a
        # redundant publisher's recovery) is delivered once per sample: its bytes go with the first.
        if self._stop:
            return
        data: bytes | None = raw.data
        size = len(raw.data)     # a bound for each sample it brought too
        if self._last_data.get(topic) is data:
            data = None
        else:
            self._last_data[topic] = raw.data
        sample = TapSample(topic, data, info.received_stamp_ns, raw.type_name, raw.type_hash, info.publisher_id,
                           info.seq, info.source_stamp_ns, raw.fields)
        with self._cond:
            self.tap_counters.received += 1
            if self._queue_bytes + size > self.max_queue_bytes:
                self.tap_counters.dropped += 1
                self._last_data.pop(topic, None)     # the envelope's bytes go with its next sample, if any
                return
            self._queue.append((sample, size))
            self._queue_bytes += size
            self._cond.notify()

    # -- worker thread --------------------------------------------------------------------
    def _run(self) -> None:
        next_tick = time.monotonic() + self.tick_period
        while True:
            with self._cond:
                if not self._queue and not self._pending_topics and not self._stop:
                    self._cond.wait(max(0.0, next_tick - time.monotonic()))
                stop = self._stop
            self._drain()
            if time.monotonic() >= next_tick:
                self._safe(self.tick)
                next_tick = time.monotonic() + self.tick_period
            if stop:
                self._drain()
                self._safe(self.finish)
                return

    def _safe(self, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except Exception:   # one bad sample or a full disk must not kill the worker silently
            self.tap_counters.handle_errors += 1
            n = self.tap_counters.handle_errors
            if n & (n - 1):     # logged at 1, 2, 4, 8...: a stream of failures cannot flood the log
                return
            log.warning("%s failed (%d errors so far)", getattr(fn, "__name__", fn), self.tap_counters.handle_errors,
                        exc_info=self.tap_counters.handle_errors == 1)

    def _drain(self) -> None:
        while True:
            with self._cond:
                topics = list(self._pending_topics)
                self._pending_topics.clear()
                item = self._queue.popleft() if self._queue else None
                if item is not None:
                    self._queue_bytes -= item[1]
            for topic in topics:
                if not self._closed:
                    self._safe(self._subscribe, topic)
            if item is None:
                return
            self._safe(self.handle, item[0])
