"""Publisher: typed message -> the node's wire format (the envelope by default) -> Zenoh put, with
QoS-derived options."""
from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable
from typing import Any, Generic, NamedTuple, TypeVar

from .context import EntityContext
from .graph import EndpointType, TopicEndpointInfo
from .message import Message, require_message_type, type_support
from .qos import QoSProfile
from .qos_events import PublisherEvents
from .qos_mapping import declare_publisher
from .redundancy import MAX_HISTORY, REPEAT_KEY, RedundantHistory
from .session_config import is_multicast_session

M = TypeVar("M", bound=Message)
REPEAT_WINDOW_FRACTION = 0.8
_time_ns = time.time_ns
_monotonic = time.monotonic


class PublishInfo(NamedTuple):
    """What ``publish()`` sent: the sample's sequence number and source stamp (its header's).
    A NamedTuple, not a frozen dataclass: one is made per publish, and a frozen dataclass's
    __init__ (object.__setattr__ per field) cost 0.29 us of a ~2.9 us publish, a NamedTuple 0.20 us."""
    seq: int
    stamp_ns: int


class PublisherClosed(RuntimeError):
    """publish() on a publisher whose node or session has closed."""


class Publisher(Generic[M]):
    """Publishes one message type on one topic; made by ``Node.create_publisher``."""

    endpoint_kind = EndpointType.PUBLISHER

    def __init__(self, context: EntityContext, msg_type: type[M], topic: str, key: str, qos: QoSProfile,
                 event_callbacks: Any = None) -> None:
        require_message_type(msg_type, "create_publisher")
        wire = context.wire
        if (qos.redundancy or qos.repeat) and not wire.carries_extra:
            raise ValueError(f"create_publisher: the {wire.name} wire format cannot carry redundancy or repeats "
                             f"(QoS redundancy={qos.redundancy}, repeat={qos.repeat}) on {topic!r}")
        self.context = context
        self.msg_type = msg_type
        self.type_support = ts = type_support(msg_type)
        self.type_name = ts.name
        self.type_hash = ts.hash
        self.topic = topic
        self.key = key
        self.qos = qos
        self.event_callbacks = event_callbacks
        # 63 bits: unique per publisher without coordination, a msgpack uint64 at most.
        self.publisher_id = secrets.randbits(63)
        self._seq = 0
        self._lock = threading.Lock()
        self._encode = ts.encode
        encoder = wire.encoder(ts, self.publisher_id)
        self._pack = encoder.pack   # under self._lock
        # Looked at per sample only by formats with an attachment (None: the envelope's fast path).
        self._attachment = encoder.attachment if wire.uses_attachment else None
        self.data_key = wire.data_key(key, ts)      # where samples go (self.key: the topic, for the graph)
        self.published = 0
        self.last_publish_mono: float | None = None
        self.last_stamp_ns = 0      # source stamp of the last sample (its seq is `sequence`)
        self._closed = False
        self._history = RedundantHistory(qos.redundancy) if qos.redundancy else None
        self._repeats = qos.repeat
        # Fixed for the publisher's life (set_repeats needs a QoS with repeat, and keeps it >= 1).
        self._plain = self._history is None and not self._repeats and self._attachment is None
        # The ROS 2 wire's common case: an attachment and nothing else (no extras to merge, no copies).
        self._attached_only = self._history is None and not self._repeats and self._attachment is not None
        # With a deadline, copies are spread over most of it (see zenoh_robot/repeater.py); the rest
        # of the deadline is margin for the copy that does arrive to be processed.
        self._repeat_window = qos.deadline * REPEAT_WINDOW_FRACTION if qos.deadline and qos.repeat else None
        self.events = PublisherEvents(context, self, event_callbacks)
        # Express samples in quick succession (a setpoint and its repeats) stall Zenoh 1.10's
        # multicast transport for good (docs/zenoh-multicast-stall.md): there express is off; the
        # cost is a batch flush of at most ~1 ms. The graph still shows the QoS asked for.
        wire_qos = qos.replace(express=False) if qos.express and is_multicast_session(context.session) else qos
        self.express_on_wire = wire_qos.express
        # A sealing format (wire/sealed.py) seals each sample once: its repeats re-send the sealed bytes.
        sealer = getattr(encoder, "sealer", None)
        seal: Callable[[bytes], bytes] | None = sealer(self.data_key, bool(qos.repeat)) if sealer is not None else None
        self._seal = seal
        self._zpub = declare_publisher(context.session, self.data_key, wire_qos)
        zput = self._zpub.put
        self._put: Callable[[bytes], Any] = zput if seal is None else (lambda payload: zput(seal(payload)))
        try:
            self._token = context.declare_endpoint(EndpointType.PUBLISHER, self)
        except BaseException:
            self.events.close()
            self._zpub.undeclare()
            raise

    @property
    def gid(self) -> int:
        """The graph's id of this publisher: the publisher id its samples carry."""
        return self.publisher_id

    @property
    def sequence(self) -> int:
        return self._seq

    def publish(self, msg: M) -> PublishInfo:
        """Send ``msg``; returns its sequence number and source stamp (for the caller's own records)."""
        if type(msg) is not self.msg_type and not isinstance(msg, self.msg_type):
            raise TypeError(f"publisher on {self.topic!r} takes {self.type_name}, got {type(msg).__name__}")
        body = self._encode(msg)   # raises ValueError for a fixed array of the wrong length
        return self.publish_raw_body(body)

    def publish_raw_body(self, body: Any, extra: dict[str, Any] | None = None) -> PublishInfo:
        """Send an already encoded body (``TypeSupport.encode``'s field values); returns its sequence
        number and source stamp. ``extra`` needs a wire format that ``carries_extra``."""
        with self._lock:
            if self._closed:
                raise PublisherClosed(f"publisher on {self.topic!r} is closed")
            self._seq = seq = self._seq + 1
            stamp = _time_ns()
            if self._plain:
                # The common case (no history, no repeats, no attachment): pack and put, nothing else.
                self._put(self._pack(seq, stamp, body, extra))
            elif self._attached_only:
                self._zpub.put(self._pack(seq, stamp, body, extra), attachment=self._attachment(seq, stamp))  # type: ignore[misc]
            else:
                self._put_with_extras(seq, stamp, body, extra)
            self.published += 1
            self.last_stamp_ns = stamp
            self.last_publish_mono = _monotonic()
        return PublishInfo(seq, stamp)

    def _put_with_extras(self, seq: int, stamp: int, body: Any, extra: dict[str, Any] | None) -> None:
        # Under self._lock: redundancy history, repeats or an attachment.
        if self._history is not None:
            carried = self._history.extra()
            extra = {**(extra or {}), **carried} if carried else extra
            self._history.record(seq, stamp, body)
        if self._repeats:
            # Tells every subscriber, whatever its own QoS, that copies follow: deduplicate.
            extra = {**(extra or {}), REPEAT_KEY: self._repeats}
        payload = self._pack(seq, stamp, body, extra)
        if self._seal is not None:
            payload = self._seal(payload)   # once: the copies below carry these very bytes
        zput = self._zpub.put
        if self._attachment is None:
            zput(payload)
        else:   # never with repeats: only formats that carry extra fields repeat (see __init__)
            self._zpub.put(payload, attachment=self._attachment(seq, stamp))
        if self._repeats and self._repeat_window is not None:
            self.context.repeater.schedule_latest(self.publisher_id, zput, payload, self._repeats,
                                                  self._repeat_window)
        elif self._repeats:   # loss is per packet: each later copy is another chance
            self.context.repeater.schedule(zput, payload, self._repeats)

    @property
    def repeats(self) -> int:
        """Delayed copies of each sample (the QoS's ``repeat`` unless adapted by :meth:`set_repeats`)."""
        return self._repeats

    @property
    def repeat_window(self) -> float | None:
        """Seconds over which a deadline stream's copies are spread (None: copies 3 ms apart)."""
        return self._repeat_window

    def set_repeats(self, copies: int, window: float | None = None) -> None:
        """Adapt the copies per sample to the measured loss (only for a QoS with ``repeat``: subscribers
        deduplicate only when the QoS says copies follow). Clamped to 1..64. With a deadline, ``window``
        (clamped to 0.8 x the deadline) sets how long the copies are spread over: copies / window is
        the packet rate while samples keep coming (``loss_feedback.repeat_plan``)."""
        if not self.qos.repeat:
            raise ValueError(f"publisher on {self.topic!r} has no repeat in its QoS")
        with self._lock:
            self._repeats = max(1, min(MAX_HISTORY, int(copies)))
            if window is not None and self._repeat_window is not None and self.qos.deadline:
                self._repeat_window = min(max(float(window), 0.001), self.qos.deadline * REPEAT_WINDOW_FRACTION)

    def assert_liveliness(self) -> None:
        """Tell subscriptions this publisher is alive (MANUAL_BY_TOPIC; publish() also does)."""
        if self._closed:
            raise PublisherClosed(f"publisher on {self.topic!r} is closed")
        self.events.assert_liveliness()

    def get_subscription_count(self) -> int:
        """Subscriptions matched with this publisher (same type, compatible QoS), in any process.

        Always 0 on a multicast session: Zenoh 1.10 does not carry the graph's declarations over that
        transport. There ``node.link_up()`` / ``node.peers()`` tell whether anyone is reachable."""
        return self.events.current_count

    def on_peer(self, appeared: bool, info: TopicEndpointInfo) -> None:
        self.events.on_peer(appeared, info)

    def destroy(self) -> None:
        with self._lock:   # waits for a publish in flight on another thread
            if self._closed:
                return
            self._closed = True
        self.events.close()
        for handle in (self._token, self._zpub):
            try:
                handle.undeclare()
            except Exception:
                pass  # already closed with the session
