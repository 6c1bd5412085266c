"""Publisher: typed message -> envelope -> Zenoh put, with QoS-derived options."""
from __future__ import annotations

import secrets
import threading
import time
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from ._wire import envelope
from .message import Message, require_message_type
from .graph import PUBLISHER, TopicEndpointInfo
from .qos import QoSProfile
from .qos_events import PublisherEvents
from .qos_mapping import declare_publisher
from ._wire.redundancy import REPEAT_KEY, RedundantHistory

if TYPE_CHECKING:
    from .node import Node

M = TypeVar("M", bound=Message)


class PublisherClosed(RuntimeError):
    """publish() on a publisher whose node or session has closed."""


class Publisher(Generic[M]):
    def __init__(self, node: "Node", msg_type: type[M], topic: str, key: str, qos: QoSProfile,
                 event_callbacks: Any = None) -> None:
        require_message_type(msg_type, "create_publisher")
        self.node = node
        self.msg_type = msg_type
        self.topic = topic
        self.key = key
        self.qos = qos
        self.event_callbacks = event_callbacks
        # 63 bits: unique per publisher without coordination, a msgpack uint64 at most.
        self.publisher_id = secrets.randbits(63)
        self._seq = 0
        self._lock = threading.Lock()
        self._type_name = msg_type._type_name
        self._type_hash = msg_type._type_hash
        self._to_wire = msg_type._to_wire
        self.published = 0
        self.last_publish_mono: float | None = None
        self.last_stamp_ns = 0      # source stamp of the last sample (its seq is `sequence`)
        self._closed = False
        self._history = RedundantHistory(qos.redundancy) if qos.redundancy else None
        self._repeats = qos.repeat
        self.events = PublisherEvents(self, event_callbacks)
        self._zpub = declare_publisher(node.session, key, qos)
        self._token = node._declare_endpoint_token(PUBLISHER, self)

    @property
    def gid(self) -> int:
        """The graph's id of this publisher: the publisher id its samples carry."""
        return self.publisher_id

    @property
    def sequence(self) -> int:
        return self._seq

    def publish(self, msg: M) -> None:
        if type(msg) is not self.msg_type and not isinstance(msg, self.msg_type):
            raise TypeError(f"publisher on {self.topic!r} takes {self._type_name}, got {type(msg).__name__}")
        body = self._to_wire(msg)   # raises ValueError for a fixed array of the wrong length
        self.publish_raw_body(body)

    def publish_raw_body(self, body: Any, extra: dict[str, Any] | None = None) -> int:
        """Send an already wire-encoded body; returns its sequence number."""
        with self._lock:
            if self._closed:
                raise PublisherClosed(f"publisher on {self.topic!r} is closed")
            self._seq += 1
            seq = self._seq
            stamp = time.time_ns()
            if self._history is not None:
                carried = self._history.extra()
                extra = {**(extra or {}), **carried} if carried else extra
                self._history.record(seq, stamp, body)
            if self._repeats:
                # Tells every subscriber, whatever its own QoS, that copies follow: deduplicate.
                extra = {**(extra or {}), REPEAT_KEY: self._repeats}
            payload = envelope.pack(self._type_name, self._type_hash, self.publisher_id, seq, stamp, body, extra)
            self._zpub.put(payload)
            if self._repeats:   # loss is per packet: each later copy is another chance
                self.node.repeater.schedule(self._zpub.put, payload, self._repeats)
            self.published += 1
            self.last_stamp_ns = stamp
            self.last_publish_mono = time.monotonic()
        return seq

    def assert_liveliness(self) -> None:
        """Tell subscriptions this publisher is alive (MANUAL_BY_TOPIC; publish() also does)."""
        if self._closed:
            raise PublisherClosed(f"publisher on {self.topic!r} is closed")
        self.events.assert_liveliness()

    def get_subscription_count(self) -> int:
        """Subscriptions matched with this publisher (same type, compatible QoS), in any process."""
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
