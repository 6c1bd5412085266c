"""Subscription: Zenoh samples -> bounded queue -> executor -> typed callback.

Zenoh's callback thread does as little as possible (copy the bytes, stamp the
arrival, append to a bounded deque). Decoding, checks and the user callback run
on the node's executor. KEEP_LAST(n) holds at most n unprocessed samples: the
oldest is dropped and counted when a new one arrives; with n = 1 a batch recovered from a
redundancy history delivers only its newest sample (the older ones count as dropped).

Hostile input: nothing a peer sends can stop, blind or fool a subscription. A sample
over ``max_sample_bytes`` is dropped before it is copied (``oversize``); the queue is
bounded by bytes (``max_queued_bytes``) as well as by count. Every step of a sample
(the wire format's decoder, type check, deduplication, schema validation of every field, lifespan,
statistics hooks, the callback) is guarded: a failure is counted by kind (``malformed``,
``type_mismatch``, ``hook_errors``, ``callback_errors``, ``internal_errors``), logged at
a bounded rate (``ratelimit``), and the subscription keeps draining. Per-publisher
tables are LRU-bounded; a forged sequence number cannot silence the real publisher
(``zenoh_robot/redundancy.py`` says why).

Raw mode (rclpy's ``raw=True``), for tools that show what is on a topic without its
Python type::

    node.create_subscription(None, "/uav1/state", cb, qos, raw=True)      # any type
    node.create_subscription(VehicleState, "/uav1/state", cb, qos, raw=True)  # that type only

``cb(raw)`` or ``cb(raw, info)`` gets a :class:`RawMessage`: ``type_name``, ``type_hash``,
``fields`` (the body as Python values: a list of field values in declaration
order, nested messages as lists) and ``data`` (the payload that carried it: with the
envelope, the whole envelope); ``info`` (:class:`MessageInfo`) has the publisher id, sequence number and source and
receive stamps. Everything else is as for a typed subscription: QoS, queue bound,
deduplication of redundant/repeated publishers, lost/expired counters, QoS events,
the graph (a raw subscription of any type announces the type hash ``any``, which
matches every publisher). With ``None`` the type check is off: samples of every type
are delivered, each naming its own type.

Two receive paths (``Node.create_subscription(..., receive=...)``):

- ``"callback"`` (the default): a Python callback on zenoh-python's delivery thread for this subscriber
  (one per subscriber, fed by Zenoh's receive thread through a channel of 256) copies each sample into the
  bounded queue above and wakes the executor. Counters are exact at arrival (``received``,
  ``dropped``, ``oversize``), the queue is bounded by count and by bytes, ``pending`` is exact.
  A sample that comes alone (over IN_PLACE_GAP_NS after the one before) while a single-threaded
  executor sits idle in a free-running ``spin()`` is handled right there, under the executor's run lock
  (``Executor.enter_in_place``): callbacks stay one at a time, and the sample skips the wake-up of a second
  thread, which was most of this path's cost over raw zenoh-python at 200 Hz-1 kHz (docs/benchmarks.md).
  IN_PLACE_SLOW_NS is wall time: on a saturated machine a preempted callback can pass it, and that subscription
  is then handled as before the change, which is the safe side.
  Samples close behind each other go to the executor, which drains them in batches while the delivery
  thread takes the next ones. A subscription whose drain once ran over IN_PLACE_SLOW_NS there is the
  executor's from then on: a long callback on the delivery thread would fill its channel and then hold
  Zenoh's receive thread for the peer, and every topic it carries.
- ``"channel"``: no Python on Zenoh's threads per sample. Zenoh keeps the samples in its own
  channel and the executor drains it in batches (``try_recv`` until empty, at most
  DRAIN_BATCH per turn). The executor is woken once per burst, not per sample: a waiter thread
  blocks in ``recv()`` (GIL released) only while the subscription is idle, hands the sample it got
  to the executor and waits until a drain finds the channel empty. Measured (docs/benchmarks.md):
  small-message throughput 0.86x / 0.98x raw (medians) against 0.69x / 0.65x for the callback path,
  p50 latency alike.
  KEEP_LAST(n): a ring channel of n (``zenoh.handlers.RingChannel``, the oldest goes first).
  KEEP_ALL: a FIFO channel of the KEEP_ALL limit (``zenoh.handlers.FifoChannel``) that, when full,
  holds back Zenoh's receive thread for that peer instead of dropping (a reliable publisher is
  then pushed back on, as a DDS KEEP_ALL reader does; its other topics wait too, so a KEEP_ALL
  channel subscription must not share a peer with a setpoint stream it can fall 10,000 samples
  behind. In its own session it is worse: a publish made on this node's executor into the full
  channel waits for a drain only that executor runs, and never returns).
  What it gives up: the ring's own overwrites are invisible to Python, so a sample the executor
  was too slow to take shows as ``lost`` (a sequence gap), not ``dropped``; ``received`` and
  ``oversize`` count at the drain; the bytes held are bounded by count x ``max_sample_bytes`` only;
  ``pending`` counts only what Python holds (the waiter's sample, a batch being handled). KEEP_LAST(n)
  still holds at most n waiting: the waiter's sample, older than the n in the ring, is then
  ``dropped``. TRANSIENT_LOCAL subscriptions always use
  the callback path.
"""
from __future__ import annotations

import inspect
import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import zenoh

from .context import EntityContext
from .graph import ANY_TYPE_HASH, EndpointType, TopicEndpointInfo
from .message import require_message_type, type_support
from .qos import DurabilityPolicy, HistoryPolicy, QoSProfile
from .qos_events import SubscriptionEvents
from .qos_mapping import declare_subscriber
from .ratelimit import RateLimitedLog
from .redundancy import AHEAD, WINDOW, Deduplicator, check_extra
from .wire import DuplicateSample, MalformedSample

M = TypeVar("M")
_time_ns = time.time_ns
_monotonic = time.monotonic
_perf_ns = time.perf_counter_ns
DRAIN_BATCH = 64  # samples per executor turn, so one busy topic cannot starve the others
# Received data is bounded (see "Hostile input" in the module doc): per sample, the default
# lets a raw 4K RGB image through; per queue, KEEP_ALL's 10,000 samples cannot hold gigabytes.
MAX_SAMPLE_BYTES = 32 << 20
MAX_QUEUED_BYTES = 128 << 20
MAX_TRACKED_PUBLISHERS = 1024   # per-publisher tables (sequence, reported mismatches): LRU beyond this
RECEIVE_PATHS = ("callback", "channel")
# The callback path runs a drain in place while the executor is idle (see _on_sample) only as long as none
# has taken longer than this: meanwhile the subscription's samples wait in zenoh-python's delivery channel
# (256), and once that is full Zenoh's receive thread for the peer waits too (docs/benchmarks.md measured
# ~3,000 samples held in all). 20 ms is 20 samples of a 1 kHz stream.
IN_PLACE_SLOW_NS = 20_000_000
IN_PLACE_GAP_NS = 300_000    # ... and only for a sample that came this long after the one before it
DEFAULT_RECEIVE = "callback"    # every guarantee exact (see the module doc); "channel" is opt-in


@dataclass(slots=True)
class MessageInfo:
    """Per-sample metadata from the sample's header (passed to 2-argument callbacks)."""
    publisher_id: int
    seq: int
    source_stamp_ns: int
    received_stamp_ns: int
    type_name: str

    @property
    def age_ms(self) -> float:
        return (self.received_stamp_ns - self.source_stamp_ns) / 1e6


@dataclass(frozen=True, slots=True)
class RawMessage:
    """A sample of a raw subscription, not decoded into a message type (see the module doc)."""
    type_name: str
    type_hash: str
    fields: Any              # the body as the wire format decoded it: field values in declaration order
    data: bytes              # the payload this sample arrived in (with the envelope: the whole envelope)
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class SubscriptionCounters:
    received: int = 0          # samples that reached this process
    delivered: int = 0         # callbacks run
    dropped: int = 0           # queue overflow (KEEP_LAST / KEEP_ALL bound)
    malformed: int = 0         # bytes the wire format does not accept, or a body that does not decode
    type_mismatch: int = 0     # a sample of another type
    lost: int = 0              # gaps in a publisher's sequence numbers
    expired: int = 0           # older than the lifespan when delivered
    incompatible: int = 0      # from a publisher whose QoS this subscription cannot accept
    callback_errors: int = 0
    oversize: int = 0          # samples over max_sample_bytes, dropped before being copied
    hook_errors: int = 0       # a sample hook (e.g. topic statistics) raised; the sample was still delivered
    internal_errors: int = 0   # anything else that failed on one sample; the subscription kept draining
    busy_ns: int = 0           # executor time draining, counted only with topic statistics (busy_pct)
    forgotten: int = 0         # publisher ids dropped from a full per-publisher table (sequence, mismatch log)
    # Highest seq per publisher id, for `lost`; bounded (least recently seen id forgotten first).
    per_publisher_seq: dict[int, int] = field(default_factory=OrderedDict)


class Subscription(Generic[M]):
    """Delivers one topic's samples to a callback on the executor; made by ``Node.create_subscription``."""

    endpoint_kind = EndpointType.SUBSCRIPTION

    def __init__(self, context: EntityContext, msg_type: type[M] | None, topic: str, key: str,
                 callback: Callable[..., Any], qos: QoSProfile, event_callbacks: Any = None,
                 *, raw: bool = False, receive: str | None = None) -> None:
        receive = DEFAULT_RECEIVE if receive is None else receive
        if receive not in RECEIVE_PATHS:
            raise ValueError(f"create_subscription: receive must be one of {RECEIVE_PATHS}, got {receive!r}")
        if msg_type is not None or not raw:
            require_message_type(msg_type, "create_subscription")
        if not callable(callback):
            raise TypeError("create_subscription: callback is not callable")
        self.context = context
        self.msg_type = msg_type
        self.raw = raw
        ts = type_support(msg_type) if msg_type is not None else None
        self.type_name = ts.name if ts is not None else ""
        self.type_hash = ts.hash if ts is not None else ANY_TYPE_HASH
        self.topic = topic
        self.key = key
        self.qos = qos
        self.callback = callback
        self.event_callbacks = event_callbacks
        self.counters = SubscriptionCounters()
        self.log = context.logger.getChild(topic.replace("/", "."))
        self._with_info = _takes_two_args(callback)
        wire = context.wire
        self._decode = wire.decoder(ts)     # raises for a format that cannot take any type
        self._attachments = wire.uses_attachment
        self.data_key = wire.data_key(key, ts)      # what is subscribed to (self.key: the topic, for the graph)
        keyed_decoder = getattr(wire, "keyed_decoder", None)     # a sealing format binds the key (wire/sealed.py)
        if keyed_decoder is not None:
            self._decode = keyed_decoder(ts, self.data_key)
        # (payload, receive stamp, attachment: None unless the wire format uses attachments)
        self._queue: deque[tuple[bytes, int, bytes | None]] = deque()
        self._dropped_unseen = 0
        self._limit = qos.queue_limit
        self._take_batch = qos.history is HistoryPolicy.KEEP_ALL
        self._lock = threading.Lock()
        self._scheduled = False
        # Everything a peer can trigger is bounded: the ids already reported (LRU), the log lines
        # (rate-limited per kind), the bytes held (per sample and per queue).
        self._mismatch_reported: OrderedDict[int, None] = OrderedDict()
        self._rlog = RateLimitedLog(self.log)
        self.max_sample_bytes = MAX_SAMPLE_BYTES
        self.max_queued_bytes = MAX_QUEUED_BYTES
        self._queued_bytes = 0
        self._seq_jumps: dict[int, int] = {}   # publisher id -> unconfirmed jump (see _track_sequence)
        self._seq_newest: int | None = None    # the id last moved to the end of per_publisher_seq
        self._hash = self.type_hash
        self._any_type = ts is None
        self._from_wire: Callable[[Any], Any] = self._raw_sample if raw else ts.decode  # type: ignore[union-attr]
        # The sample being handled in raw mode: (type_name, type_hash, extra, data).
        self._raw_env: tuple[str, str, dict[str, Any], bytes] | None = None
        self._executor = context.executor
        self._run_here: Callable[[Callable[[], None]], bool] = getattr(self._executor, "run_here", _never_here)
        self._drain_work = self._drain     # one bound method, not a new one per scheduling
        # Callback path: may a lone sample be handled on the delivery thread (_on_sample)?
        self._enter_in_place: Callable[[], bool] = getattr(self._executor, "enter_in_place", _never_in_place)
        self._in_place = True
        self._last_arrival_ns = 0
        self._lifespan_ns = int(qos.lifespan * 1e9) if qos.lifespan else None
        self.sample_hooks: list[Callable[[M, MessageInfo], None]] = []
        self._statistics: Any = None   # a TopicStatisticsCollector when statistics are enabled
        # Redundant or repeated publishers send samples more than once: deliver each once, in order.
        self.dedup = Deduplicator() if (qos.redundancy or qos.repeat) else None
        # KEEP_LAST(1): of a recovered batch only the newest is delivered (see _keep_newest).
        self._newest_only = qos.history is HistoryPolicy.KEEP_LAST and qos.depth == 1
        # Told of each sample a newer one of its batch superseded: (publisher id, seq, source stamp ns,
        # receive stamp ns). For records of what reached this process (arrivals, ages), not for the data.
        self.superseded: Callable[[int, int, int, int], None] | None = None
        self.gid = secrets.randbits(63)
        self.last_sample_mono: float | None = None
        self.events = SubscriptionEvents(context, self, event_callbacks)
        if qos.durability is DurabilityPolicy.TRANSIENT_LOCAL:
            receive = "callback"    # the advanced subscriber's history replay stays on the proven path
        self.receive = receive
        self._closed = False
        self.redeclared = 0      # times the Zenoh subscriber was declared again (redeclare)
        # Channel path: the sample the waiter thread got from recv(), and its go-ahead to block again.
        self._first: Any = None
        self._backlog: deque[Any] = deque()     # taken from the channel, not yet handled (executor only)
        # The waiter's go-ahead: released = it may block in recv() again. A lock, not an Event: two C
        # calls per burst instead of a dozen Python ones (Condition, notify) on the latency path.
        self._idle = threading.Lock()
        self._idle.acquire()
        if receive == "channel":
            self._drain_some = self._drain_channel    # type: ignore[method-assign]
            # KEEP_ALL loses nothing: a FIFO that, full, holds Zenoh's receive back (reliable streams
            # then push back on the publisher). KEEP_LAST: a ring that overwrites its oldest.
            handler: Any = (zenoh.handlers.FifoChannel(self._limit) if self._take_batch
                            else zenoh.handlers.RingChannel(max(1, self._limit)))
            self._zsub = declare_subscriber(context.session, self.data_key, qos, handler)
            self._set_idle()
            self._waiter = threading.Thread(target=self._wait_loop, daemon=True, name=f"zr-recv-{topic}")
            self._waiter.start()
        else:
            self._zsub = declare_subscriber(context.session, self.data_key, qos, self._on_sample)
        try:
            self._token = context.declare_endpoint(EndpointType.SUBSCRIPTION, self)
        except BaseException:
            self.events.close()
            self._zsub.undeclare()
            raise

    # -- Zenoh thread --------------------------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        # Zenoh's thread: never raises, never copies what it will drop.
        try:
            payload = sample.payload
            size = len(payload)
            if size > self.max_sample_bytes:
                with self._lock:
                    self.counters.received += 1
                    self.counters.oversize += 1
                self._rlog.warning("oversize", "sample of %d bytes on %r dropped: the limit is %d bytes "
                                   "(Subscription.max_sample_bytes)", size, self.topic, self.max_sample_bytes)
                return
            data = payload.to_bytes()
            attachment = None
            if self._attachments:
                zattachment = sample.attachment
                attachment = None if zattachment is None else zattachment.to_bytes()
        except Exception as exc:
            self._internal_error("receive", exc)
            return
        now = _time_ns()
        with self._lock:
            self.counters.received += 1
            queue = self._queue
            # A sample that comes alone (the queue empty, none close before it) to an idle executor is
            # handled right here, on zenoh-python's delivery thread for this subscriber: one thread hop,
            # as raw zenoh-python's callback, instead of waking the executor (a second hop). Samples close
            # behind each other go to the executor, which drains them in batches while this thread takes
            # the next ones from Zenoh (a flood handled here ran slower, docs/benchmarks.md).
            alone = (now - self._last_arrival_ns > IN_PLACE_GAP_NS and not queue and not self._scheduled
                     and self._in_place)
            self._last_arrival_ns = now
            if alone:
                self._scheduled = True      # the executor's drains keep off while this one is handled here
            else:
                # Bounded by count (depth, or the KEEP_ALL limit) and by bytes: the oldest goes first.
                if queue and (len(queue) >= self._limit or self._queued_bytes + size > self.max_queued_bytes):
                    self._make_room(size)
                queue.append((data, now, attachment))
                self._queued_bytes += size
                if self._scheduled:
                    return      # the drain already queued picks this one up: one executor wake-up per drain
                self._scheduled = True
        if alone:
            if self._enter_in_place():
                self._handle_in_place(data, now, attachment)
                with self._lock:
                    if not queue:
                        self._scheduled = False
                        return
            else:   # the executor is busy (or spins for a caller): it takes the sample
                with self._lock:
                    self._make_room(size)   # (the rare path: no inline test first, as above)
                    queue.append((data, now, attachment))
                    self._queued_bytes += size
        self._executor.submit(self._drain_work)

    def _handle_in_place(self, data: bytes, received_ns: int, attachment: bytes | None) -> None:
        # Holding the executor's run lock (Executor.enter_in_place). Meanwhile this subscription's samples
        # wait in the delivery thread's channel, and once it is full Zenoh's receive thread for the peer
        # waits too (IN_PLACE_SLOW_NS): a subscription whose callback once took that long here is the
        # executor's from then on.
        start = _perf_ns()
        try:
            self._handle(data, received_ns, attachment)
        except Exception as exc:   # a bug or a hostile sample: count it, keep the others coming
            self._internal_error("handle", exc)
        except BaseException as exc:    # SystemExit, KeyboardInterrupt: the spin raises it, as it would have
            self._executor.raise_in_spin(exc)
        finally:
            self._executor.leave_in_place()
            took = _perf_ns() - start
            if self._statistics is not None:
                self.counters.busy_ns += took
            if took > IN_PLACE_SLOW_NS:
                self._in_place = False
                self.log.info("callbacks of %r run on the executor from now on: one took over %d ms run on "
                              "the delivery thread", self.topic, IN_PLACE_SLOW_NS // 1_000_000)

    # -- channel path: waiter thread -------------------------------------------------
    def _wait_loop(self) -> None:
        # Blocks in recv() only while no drain is scheduled: one executor wake-up per burst of samples.
        recv, go = self._zsub.recv, self._idle.acquire
        while True:
            go()
            if self._closed:
                return
            try:
                sample = recv()
            except Exception:   # undeclared (destroy, session closed): nothing more will come
                return
            if self._closed:
                return
            self._first = sample
            # An idle executor: handle it on this thread (no second wake-up, executor.py says why).
            if not self._run_here(self._drain_work):
                self._executor.submit(self._drain_work)

    def _make_room(self, size: int) -> None:
        # Under self._lock (the rare path of _on_sample: the queue is full).
        queue = self._queue
        while queue and (len(queue) >= self._limit or self._queued_bytes + size > self.max_queued_bytes):
            old = queue.popleft()[0]
            self._queued_bytes -= len(old)
            self.counters.dropped += 1
            self._dropped_unseen += 1   # will show as a sequence gap: not a network loss

    # -- executor ------------------------------------------------------------------
    def _drain(self) -> None:
        more = True
        try:
            more = self._drain_some()
        finally:
            # Whatever happened to a sample, a subscription with queued samples stays scheduled
            # and one without is unscheduled (in _drain_some, under the lock): it never stops draining.
            if more:
                self._executor.submit(self._drain_work)   # give other entities a turn

    def _drain_timed(self) -> None:
        # _drain with statistics on (the `statistics` setter picks it): one clock pair per batch, not
        # per sample, gives the executor time this stream takes (topic_statistics: busy_pct). Without
        # statistics _drain runs, which times nothing and checks nothing more. No lock: drains of one
        # subscription run one at a time (_scheduled), and the collector only reads the total.
        more = True
        start = _perf_ns()
        try:
            more = self._drain_some()
        finally:
            self.counters.busy_ns += _perf_ns() - start
            if more:
                self._executor.submit(self._drain_work)

    def _drain_some(self) -> bool:
        """Handle up to DRAIN_BATCH samples; False once the queue is empty (then unscheduled)."""
        lock, queue, handle = self._lock, self._queue, self._handle
        if self._take_batch:
            # KEEP_ALL never drops, so samples may leave the queue in batches: one lock per batch
            # instead of one per sample, which the Zenoh thread would otherwise contend for.
            handled = 0
            while True:
                with lock:
                    if not queue:
                        self._scheduled = False
                        return False
                    if handled >= DRAIN_BATCH:
                        return True     # more is waiting: another drain, after the others' turn
                    batch = [queue.popleft() for _ in range(min(len(queue), DRAIN_BATCH))]
                    size = 0
                    for data, _, _ in batch:
                        size += len(data)
                    self._queued_bytes -= size
                for data, received, attachment in batch:
                    try:
                        handle(data, received, attachment)
                    except Exception as exc:   # a bug or a hostile sample: count it, keep the others coming
                        self._internal_error("handle", exc)
                handled += len(batch)
        # KEEP_LAST(n): a sample stays in the queue (where a newer one can still replace it) until
        # it is handled, so at most n are ever waiting.
        for _ in range(DRAIN_BATCH):
            with lock:
                if not queue:
                    self._scheduled = False
                    return False
                data, received, attachment = queue.popleft()
                self._queued_bytes -= len(data)
            try:
                handle(data, received, attachment)
            except Exception as exc:
                self._internal_error("handle", exc)
        # Unscheduled here when the batch emptied the queue: no idle wake-up follows a full batch.
        with lock:
            if not queue:
                self._scheduled = False
                return False
        return True

    def _drain_channel(self) -> bool:
        """Channel path: handle up to DRAIN_BATCH samples from Zenoh's channel; False once it is empty
        (then the waiter may block in recv() again)."""
        first, self._first = self._first, None
        backlog, try_recv, handle = self._backlog, self._zsub.try_recv, self._handle
        counters = self.counters
        limit = self.max_sample_bytes
        attachments = self._attachments
        handled = 0
        try:
            sample = None
            if first is not None:
                if self._take_batch:
                    backlog.append(first)
                elif not backlog and (sample := try_recv()) is None:
                    sample = first      # the common case of a stream at a steady rate: it came alone
                else:
                    if sample is not None:      # a newer one waits behind it: take the ring in order
                        backlog.append(sample)
                        sample = None
                    # KEEP_LAST(n): the waiter's sample is older than all the ring holds. With n newer
                    # ones behind it, it is the n+1-th waiting: drop it as the callback path would.
                    while len(backlog) < self._limit:
                        newer = try_recv()
                        if newer is None:
                            break
                        backlog.append(newer)
                    if len(backlog) >= self._limit:
                        counters.received += 1
                        counters.dropped += 1
                        with self._lock:
                            self._dropped_unseen += 1   # will show as a sequence gap: not a network loss
                    else:
                        backlog.appendleft(first)
            if sample is None:
                sample = backlog.popleft() if backlog else try_recv()
            while sample is not None:
                counters.received += 1
                try:
                    payload = sample.payload
                    size = len(payload)
                    if size > limit:
                        counters.oversize += 1
                        self._rlog.warning("oversize", "sample of %d bytes on %r dropped: the limit is %d bytes "
                                           "(Subscription.max_sample_bytes)", size, self.topic, limit)
                    else:
                        attachment = None
                        if attachments:
                            zattachment = sample.attachment
                            attachment = None if zattachment is None else zattachment.to_bytes()
                        handle(payload.to_bytes(), _time_ns(), attachment)
                except Exception as exc:   # a bug or a hostile sample: count it, keep the others coming
                    self._internal_error("handle", exc)
                handled += 1
                if handled >= DRAIN_BATCH:
                    return True     # still scheduled: _drain submits the next turn, the waiter stays parked
                sample = backlog.popleft() if backlog else try_recv()
        except Exception as exc:    # try_recv on an undeclared subscriber: the subscription is going away
            if not self._closed:
                self._internal_error("receive", exc)
        self._set_idle()
        return False

    def _set_idle(self) -> None:
        try:
            self._idle.release()
        except RuntimeError:    # already released (destroy beside a drain's end): one go-ahead is enough
            pass

    def _handle(self, data: bytes, received_ns: int, attachment: bytes | None = None) -> None:
        # The hot path: the header stays in locals (no object per sample), the common case (no
        # redundancy, the next sequence number, no lifespan) takes no extra call. With the envelope,
        # self._decode is envelope.unpack_fields itself.
        # A local, then the call: Python 3.11 cannot specialise a call of a function kept on the
        # instance (self._decode(...)), and this saves that lookup on every sample.
        decode = self._decode
        try:
            type_name, type_hash, pub_id, seq, stamp_ns, body, extra = decode(data, attachment)
        except DuplicateSample:
            return      # a sealed copy of a sample already delivered: counted by the format, not malformed
        except MalformedSample as exc:
            self._malformed(f"{exc} ({len(data)} bytes)")
            return
        if extra:   # almost always empty: only redundant/repeating publishers fill it
            bad_extra = check_extra(extra)
            if bad_extra is not None:
                self._malformed(bad_extra)
                return
        blocked = self.events.blocked
        if blocked and pub_id in blocked:
            self.counters.incompatible += 1    # reported once as an incompatible-QoS event
            return
        if type_hash != self._hash and not self._any_type:
            self._type_mismatch(type_name, type_hash, pub_id)
            return
        if self.raw:
            self._raw_env = (type_name, type_hash, extra, data)
        dedup = self.dedup
        if dedup is None:
            if not extra:
                self._deliver_sample(type_name, pub_id, seq, stamp_ns, body, received_ns)
                return
            # A redundant or repeating publisher, whatever this subscription's own QoS: from now
            # on, deliver each of its samples once.
            dedup = self.dedup = Deduplicator()
        fresh = dedup.fresh(pub_id, seq, stamp_ns, body, extra, received_ns)
        if len(fresh) > 1 and self._newest_only:
            fresh = self._keep_newest(pub_id, fresh, received_ns)
        for fresh_seq, stamp, fresh_body in fresh:
            self._deliver_sample(type_name, pub_id, fresh_seq, stamp, fresh_body, received_ns)

    def _keep_newest(self, pub_id: int, fresh: list[tuple[int, int, Any]],
                     received_ns: int) -> list[tuple[int, int, Any]]:
        # KEEP_LAST(1) applied to a batch recovered from a carried history: the batch arrived at once,
        # as n samples would in a depth-1 queue, so only the newest is delivered and the rest count as
        # dropped (not lost: _track_sequence excuses them). A setpoint stream must not hand a consumer
        # targets up to k periods old, oldest first, right after a fade (issue #29).
        newest = max(fresh, key=lambda f: (f[1], f[0]))
        skipped = len(fresh) - 1
        with self._lock:
            self.counters.dropped += skipped
            self._dropped_unseen += skipped
        hook = self.superseded
        if hook is not None:
            for seq, stamp, _ in fresh:
                if seq != newest[0]:
                    try:
                        hook(pub_id, seq, stamp, received_ns)
                    except Exception:
                        self.counters.hook_errors += 1
                        self._rlog.error("superseded", "superseded hook on %r raised (error %d)", self.topic,
                                         self.counters.hook_errors, exc_info=True)
        return [newest]

    def _type_mismatch(self, type_name: str, type_hash: str, pub_id: int) -> None:
        self.counters.type_mismatch += 1
        if pub_id not in self._mismatch_reported:
            self._mismatch_reported[pub_id] = None
            if len(self._mismatch_reported) > MAX_TRACKED_PUBLISHERS:
                self._mismatch_reported.popitem(last=False)
                self.counters.forgotten += 1
            self._rlog.error("type_mismatch", "type mismatch on %r: publisher %x sends %s (hash %s), this "
                             "subscription expects %s (hash %s); its samples are dropped", self.topic,
                             pub_id, type_name[:100], type_hash[:64], self.type_name, self._hash)

    def _deliver_sample(self, type_name: str, pub_id: int, seq: int, stamp_ns: int, body: Any,
                        received_ns: int) -> None:
        from_wire = self._from_wire     # a local first, as decode in _handle
        try:
            msg = from_wire(body)
        except Exception as exc:    # ValidationError names the field; anything else is malformed too
            self._malformed(f"body does not decode as {self.type_name}: {exc}")
            return
        events = self.events
        table = self.counters.per_publisher_seq
        if pub_id == self._seq_newest and not self._seq_jumps and table.get(pub_id) == seq - 1:
            table[pub_id] = seq     # _track_sequence's common case, without the call
        else:
            gap = self._track_sequence(pub_id, seq)
            if gap:
                events.on_lost(gap)
        if self._lifespan_ns is not None or events.lifespans_ns:
            # Lifespan is the publisher's promise (ROS 2): its offered one, else this profile's.
            lifespan_ns = events.lifespans_ns.get(pub_id, self._lifespan_ns)
            if lifespan_ns is not None and _time_ns() - stamp_ns > lifespan_ns:   # age when delivered
                self.counters.expired += 1
                return
        self.last_sample_mono = now = _monotonic()
        if events.leased_writers:
            events.on_sample(pub_id, now)
        hooks = self.sample_hooks
        with_info = self._with_info
        if hooks or with_info:
            info = MessageInfo(pub_id, seq, stamp_ns, received_ns, type_name)
            for hook in hooks:
                try:
                    hook(msg, info)
                except Exception:
                    self.counters.hook_errors += 1
                    self._rlog.error("hook", "sample hook %r on %r raised (error %d); the sample is still "
                                     "delivered", hook, self.topic, self.counters.hook_errors, exc_info=True)
        # deliver(), inline: one call fewer per sample.
        try:
            if with_info:
                self.callback(msg, info)
            else:
                self.callback(msg)      # a 1-argument callback: no info was built
            self.counters.delivered += 1
        except Exception:
            self._callback_error()

    def _raw_sample(self, body: Any) -> RawMessage:
        # Raw mode's decoder: the sample being handled names the type (set in _handle, same turn).
        if self._raw_env is None:
            raise ValueError("raw sample without its header")
        type_name, type_hash, extra, data = self._raw_env
        return RawMessage(type_name, type_hash, body, data, extra)

    def deliver(self, msg: M, info: MessageInfo) -> None:
        try:
            if self._with_info:
                self.callback(msg, info)
            else:
                self.callback(msg)
            self.counters.delivered += 1
        except Exception:
            self._callback_error()

    def _callback_error(self) -> None:
        # In the except block of a callback: exc_info logs its traceback.
        self.counters.callback_errors += 1
        self._rlog.error("callback", "callback for topic %r raised (error %d); the node keeps running",
                         self.topic, self.counters.callback_errors, exc_info=True)

    def _track_sequence(self, pub_id: int, seq: int) -> int:
        """Samples lost before ``seq`` (0 if none). A jump is counted only once the next sample
        continues from it: one forged sequence number far ahead is then no loss of thousands,
        and a sample the stream does not follow is forgotten (the real stream goes on counting)."""
        table = self.counters.per_publisher_seq
        jumps = self._seq_jumps
        if pub_id == self._seq_newest and not jumps and table.get(pub_id) == seq - 1:
            # The common case: the next seq of the publisher seen last (already newest in LRU order).
            table[pub_id] = seq
            return 0
        self._seq_newest = pub_id
        last = table.pop(pub_id, None)      # re-inserted below: the table is kept in LRU order
        if last is None:
            if len(table) >= MAX_TRACKED_PUBLISHERS:
                jumps.pop(table.popitem(last=False)[0], None)   # type: ignore[call-arg]
                self.counters.forgotten += 1
            table[pub_id] = seq
            return 0
        pend = jumps.pop(pub_id, None)
        gap = 0
        if pend is not None and pend < seq <= pend + AHEAD:
            # The jump to `pend` is confirmed; across a restart (far jump) nothing before it counts.
            gap = (pend - last - 1 if last < pend <= last + AHEAD else 0) + (seq - pend - 1)
            last = seq
        elif last - WINDOW < seq <= last + 1:
            last = max(last, seq)           # the next one, or late
        else:
            jumps[pub_id] = seq             # a jump (gap, restart or forgery): wait for the next sample
        table[pub_id] = last
        if gap > 0:
            with self._lock:    # samples this subscription dropped itself (KEEP_LAST) were not lost
                excused = min(gap, self._dropped_unseen)
                self._dropped_unseen -= excused
            gap -= excused
            self.counters.lost += gap
            return gap
        return 0

    def _malformed(self, why: str) -> None:
        self.counters.malformed += 1
        self._rlog.warning("malformed", "malformed sample on %r dropped: %s (%d so far)", self.topic, why[:300],
                           self.counters.malformed)

    def _internal_error(self, where: str, exc: BaseException) -> None:
        self.counters.internal_errors += 1
        self._rlog.error("internal", "sample on %r failed in %s: %s: %s (%d so far); the subscription keeps "
                         "draining", self.topic, where, type(exc).__name__, str(exc)[:300],
                         self.counters.internal_errors, exc_info=True)

    @property
    def statistics(self) -> Any:
        """The TopicStatisticsCollector when statistics are enabled, else None."""
        return self._statistics

    @statistics.setter
    def statistics(self, collector: Any) -> None:
        self._statistics = collector
        # The drain scheduled from now on: timed only with a collector to report to.
        self._drain_work = self._drain if collector is None else self._drain_timed

    @property
    def pending(self) -> int:
        """Samples waiting for the executor (channel path: only the one the waiter holds)."""
        if self.receive == "channel":
            return len(self._backlog) + (self._first is not None)
        with self._lock:
            return len(self._queue)

    def on_peer(self, appeared: bool, info: TopicEndpointInfo) -> None:
        self.events.on_peer(appeared, info)

    def get_publisher_count(self) -> int:
        """Publishers matched with this subscription (same type, compatible QoS), in any process.

        Always 0 on a multicast session (no declarations cross it): use ``node.link_up()`` there."""
        return self.events.current_count

    def redeclare(self) -> bool:
        """Declare this subscription's Zenoh subscriber again (the new one first, then the old one goes): what a
        silent stream (``zenoh_robot.silence``) tries once, in case the declaration never reached the publisher's
        side. The queue, counters and graph token stay. Only the callback path (the channel path's waiter is
        bound to its channel) and not transient local; False when not done. Thread-safe; the rare path: nothing
        per sample."""
        if self.receive != "callback" or self._closed or self.qos.durability is DurabilityPolicy.TRANSIENT_LOCAL:
            return False    # (a transient-local subscriber declared again would replay its history)
        try:
            fresh = declare_subscriber(self.context.session, self.data_key, self.qos, self._on_sample)
        except Exception as exc:   # a closing session: the stream stays as it was
            self.log.warning("re-declaring the subscription of %r failed: %s", self.topic, exc)
            return False
        with self._lock:
            old, self._zsub = self._zsub, fresh
            self.redeclared += 1
        try:
            old.undeclare()
        except Exception:
            pass
        self.log.info("subscription of %r re-declared (silent stream)", self.topic)
        return True

    def destroy(self) -> None:
        if self.statistics is not None:
            self.statistics.destroy()
        self.events.close()
        self._closed = True
        for handle in (self._token, self._zsub):
            try:
                handle.undeclare()
            except Exception:
                pass
        self._set_idle()    # a parked waiter sees _closed and ends


def _never_here(work: Callable[[], None]) -> bool:
    return False


def _never_in_place() -> bool:
    return False


def _takes_two_args(fn: Callable[..., Any]) -> bool:
    try:
        params = [p for p in inspect.signature(fn).parameters.values()
                  if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is p.empty]
    except (TypeError, ValueError):
        return False
    return len(params) >= 2
