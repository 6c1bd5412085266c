"""Replay a flight log onto the network (``zenoh-robot bag play``).

The raw channels hold each sample's wire bytes, so replay puts exactly those bytes on
the topic's key, with the original spacing (scaled by ``rate``), from a Zenoh publisher
declared with the QoS the original publisher announced (one per original publisher:
publishers of one topic that differed in QoS keep their own), and announces each
original publisher in the graph (same type, hash, QoS and publisher id): typed
subscriptions match and decode as if the flight were live. ``restamp`` rewrites the
source stamp to now (for consumers that check age or lifespan); sequence numbers are kept.

The raw channels hold envelope bytes (``encodings.RAW_ENVELOPE_SCHEMA``), so replay speaks the
envelope format (``zenoh_robot.wire.ENVELOPE``: its keys and graph tokens) whatever the
node's own format.

``loop``: every pass after the first speaks as new publishers (an id derived from the
original and the pass number, announced afresh), since subscriptions deliver a
publisher's sequence number once: the same ids again would be dropped as duplicates.
"""
from __future__ import annotations

import hashlib
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zenoh_robot.graph import EndpointType, TopicEndpointInfo, decode_qos
from zenoh_robot.qos import SYSTEM_DEFAULT, QoSProfile
from zenoh_robot.qos_mapping import declare_publisher
from zenoh_robot.wire import ENVELOPE, MalformedSample

from .encodings import RAW_ENVELOPE_SCHEMA, unwrap_envelope
from .info import Record, iter_records

if TYPE_CHECKING:
    from zenoh_robot.node import Node

log = logging.getLogger("zenoh_robot.bag")
MAX_PUBLISHERS = 1024
ID_MASK = (1 << 63) - 1      # publisher ids are 63-bit (Publisher.publisher_id)


def loop_publisher_id(original: int, loop: int) -> int:
    """The id the original publisher speaks as on pass ``loop`` (0: its own)."""
    if loop == 0:
        return original
    digest = hashlib.blake2b(f"{original:x}/{loop}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") & ID_MASK or 1


@dataclass
class PlayCounters:
    published: int = 0
    skipped: int = 0            # not a raw channel we can replay, or filtered out
    malformed: int = 0
    loops: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)


class BagPlayer:
    def __init__(self, node: "Node", path: str | Path, topics: list[str] | None = None, *, rate: float = 1.0,
                 loop: bool = False, restamp: bool = False, passes: int | None = None) -> None:
        """``passes``: with ``loop``, stop after that many passes through the file (None: until stopped)."""
        if not rate > 0:
            raise ValueError(f"rate must be > 0, got {rate}")
        if passes is not None and passes < 1:
            raise ValueError(f"passes must be >= 1, got {passes}")
        self.passes = passes
        self.node = node
        self.path = Path(path)
        self.topics = {"/" + t.strip("/") for t in topics} if topics else None
        self.rate = rate
        self.loop = loop
        self.restamp = restamp
        self.counters = PlayCounters()
        self._pubs: dict[tuple[str, str, int], Any] = {}
        self._tokens: dict[tuple[str, int], Any] = {}
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    def _publisher(self, rec: Record, publisher_id: int) -> tuple[Any, QoSProfile, str] | None:
        meta = rec.channel.metadata
        topic, type_name = meta.get("zr.topic", ""), meta.get("zr.type", "")
        if not topic.startswith("/") or not type_name:
            return None
        key = (topic, type_name, publisher_id)
        entry = self._pubs.get(key)
        if entry is None:
            if len(self._pubs) >= MAX_PUBLISHERS:
                return None
            try:
                qos = decode_qos(meta["zr.qos"]) if "zr.qos" in meta else SYSTEM_DEFAULT
            except (ValueError, KeyError):
                qos = SYSTEM_DEFAULT
            zpub = declare_publisher(self.node.session, ENVELOPE.data_key(topic[1:], None), qos)
            entry = self._pubs[key] = (zpub, qos, meta.get("zr.hash", ""))
        return entry

    def _announce(self, topic: str, type_name: str, type_hash: str, qos: QoSProfile, publisher_id: int) -> None:
        tkey = (topic, publisher_id)
        if tkey in self._tokens or len(self._tokens) >= MAX_PUBLISHERS:
            return
        n = self.node
        self._tokens[tkey] = n.session.liveliness().declare_token(ENVELOPE.graph.endpoint_token(TopicEndpointInfo(
            n.name, n.get_namespace(), topic, type_name, type_hash, EndpointType.PUBLISHER, publisher_id, qos, n.zid)))

    def play(self, duration: float | None = None) -> PlayCounters:
        """Publish until the file ends (or forever with ``loop``); returns the counters."""
        end = None if duration is None else time.monotonic() + duration
        while not self._stop.is_set():
            self._play_once(end, self.counters.loops)
            if not self.loop or self._stop.is_set() or (end is not None and time.monotonic() >= end) or \
                    (self.passes is not None and self.counters.loops + 1 >= self.passes):
                break
            self.counters.loops += 1
            self._forget_tokens()    # last pass's publishers are gone; the next pass announces its own
        return self.counters

    def _forget_tokens(self) -> None:
        for token in self._tokens.values():
            try:
                token.undeclare()
            except Exception:
                pass
        self._tokens.clear()

    def _play_once(self, end: float | None, loop: int = 0) -> None:
        t0_wall: float | None = None
        t0_log = 0
        for rec in iter_records(self.path):
            if self._stop.is_set() or (end is not None and time.monotonic() >= end):
                return
            if not isinstance(rec, Record) or rec.schema is None or rec.schema.name != RAW_ENVELOPE_SCHEMA:
                continue
            topic = rec.channel.metadata.get("zr.topic", "")
            if self.topics is not None and topic not in self.topics:
                self.counters.skipped += 1
                continue
            try:
                data = unwrap_envelope(rec.message.data)
                env = ENVELOPE.unpack(data)
            except (MalformedSample, ValueError):
                self.counters.malformed += 1
                continue
            entry = self._publisher(rec, env.publisher_id)
            if entry is None:
                self.counters.skipped += 1
                continue
            zpub, qos, type_hash = entry
            pid = loop_publisher_id(env.publisher_id, loop)
            self._announce(topic, env.type_name, env.type_hash or type_hash, qos, pid)
            if t0_wall is None:
                t0_wall, t0_log = time.monotonic(), rec.message.log_time
                # Give subscriptions a moment to see the graph announcement before the first sample.
                time.sleep(0.2)
                t0_wall += 0.2
            due = t0_wall + (rec.message.log_time - t0_log) / 1e9 / self.rate
            wait = due - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            if self.restamp or pid != env.publisher_id:
                data = ENVELOPE.pack(env._replace(publisher_id=pid,
                                                  stamp_ns=time.time_ns() if self.restamp else env.stamp_ns))
            zpub.put(data)
            self.counters.published += 1
            self.counters.per_topic[topic] = self.counters.per_topic.get(topic, 0) + 1

    def close(self) -> None:
        for handle in [*self._tokens.values(), *(p for p, _, _ in self._pubs.values())]:
            try:
                handle.undeclare()
            except Exception:
                pass
        self._tokens.clear()
        self._pubs.clear()
