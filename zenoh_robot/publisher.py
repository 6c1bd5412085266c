"""Publisher: typed message -> envelope -> Zenoh put, with QoS-derived options."""
from __future__ import annotations

import secrets
import threading
import time
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from . import envelope
from .message import Message, require_message_type
from .qos import QoSProfile
from .qos_mapping import publisher_options
from .redundancy import REPEAT_KEY, RedundantHistory

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
        self._zpub = node.session.declare_publisher(key, **publisher_options(qos))
        self.published = 0
        self.last_publish_mono: float | None = None
        self.last_stamp_ns = 0      # source stamp of the last sample (its seq is `sequence`)
        self._closed = False
        self._history = RedundantHistory(qos.redundancy) if qos.redundancy else None
        self._repeats = qos.repeat

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

    def get_subscription_count(self) -> int:
        return self.node.count_subscribers(self.topic)

    def destroy(self) -> None:
        with self._lock:   # waits for a publish in flight on another thread
            self._closed = True
        try:
            self._zpub.undeclare()
        except Exception:
            pass  # already closed with the session
