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
node's own format. ROS 2 channels (``cdr`` with a ``ros2msg`` schema: ``bag record --ros2``'s, or a
rosbag2 MCAP's) play on the ROS 2 wire (play_ros2.py): the node's own when it speaks ROS 2, else
``ros2_wire()`` (``ROS_DOMAIN_ID``, else 0). Both kinds share one clock: the recording's order and
spacing. A channel that cannot be played is reported once, in one line (``on_unplayable``); the
JSON copies and foxglove.* views are derived from the others and not played.

``loop``: every pass after the first speaks as new publishers (an id derived from the
original and the pass number, announced afresh), since subscriptions deliver a
publisher's sequence number once: the same ids again would be dropped as duplicates.
"""
from __future__ import annotations

import hashlib
import logging
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zenoh_robot.graph import EndpointType, TopicEndpointInfo, decode_qos
from zenoh_robot.qos import SYSTEM_DEFAULT, QoSProfile
from zenoh_robot.qos_mapping import declare_publisher
from zenoh_robot.wire import ENVELOPE, MalformedSample, Ros2WireFormat, ros2_wire

from .encodings import CDR, RAW_ENVELOPE_SCHEMA, unwrap_envelope
from .info import Record, check_mcap, iter_records
from .play_ros2 import Ros2Sender, Unplayable, describe, node_token

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
    ros2_published: int = 0     # of published: samples of ROS 2 cdr channels
    per_topic: dict[str, int] = field(default_factory=dict)
    unplayable: dict[str, str] = field(default_factory=dict)     # channel -> why not (reported once)


class BagPlayer:
    def __init__(self, node: "Node", path: str | Path, topics: list[str] | None = None, *, rate: float = 1.0,
                 loop: bool = False, restamp: bool = False, passes: int | None = None,
                 on_unplayable: Callable[[str], None] | None = None) -> None:
        """``passes``: with ``loop``, stop after that many passes through the file (None: until stopped).
        ``on_unplayable``: called once per channel that cannot be played, with one line (default: logged)."""
        if not rate > 0:
            raise ValueError(f"rate must be > 0, got {rate}")
        if passes is not None and passes < 1:
            raise ValueError(f"passes must be >= 1, got {passes}")
        self.passes = passes
        self.node = node
        self.path = Path(path)
        check_mcap(self.path)
        self.topics = {"/" + t.strip("/") for t in topics} if topics else None
        self.rate = rate
        self.loop = loop
        self.restamp = restamp
        self.counters = PlayCounters()
        self._pubs: dict[tuple[str, str, int], Any] = {}
        self._tokens: dict[tuple[str, int], Any] = {}
        self._stop = threading.Event()
        self._on_unplayable = on_unplayable or log.warning
        self._ros2: Ros2WireFormat | None = node.wire if isinstance(node.wire, Ros2WireFormat) else None
        self._ros2_node_token: Any = None
        self._senders: dict[int, Ros2Sender | None] = {}    # channel id -> its publisher (None: not played)

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
            if not isinstance(rec, Record):
                continue
            send = self._prepare(rec, loop)
            if send is None:
                continue
            if t0_wall is None:
                t0_wall, t0_log = time.monotonic(), rec.message.log_time
                # Give subscriptions a moment to see the graph announcement before the first sample.
                time.sleep(0.2)
                t0_wall += 0.2
            due = t0_wall + (rec.message.log_time - t0_log) / 1e9 / self.rate
            wait = due - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            topic = send()
            self.counters.published += 1
            self.counters.per_topic[topic] = self.counters.per_topic.get(topic, 0) + 1

    def _prepare(self, rec: Record, loop: int) -> Callable[[], str] | None:
        """What puts ``rec`` on the wire and returns its topic, its publisher announced; None: not played."""
        if rec.channel.message_encoding == CDR:
            return self._prepare_cdr(rec)
        if rec.schema is not None and rec.schema.name == RAW_ENVELOPE_SCHEMA:
            return self._prepare_raw(rec, loop)
        derived = "zr.type" in rec.channel.metadata or (rec.schema is not None
                                                        and rec.schema.name.startswith("foxglove."))
        wanted = self.topics is None or "/" + rec.channel.topic.strip("/") in self.topics
        if not derived and wanted and rec.channel.id not in self._senders:
            self._senders[rec.channel.id] = None
            self._refuse(rec, f"message encoding {rec.channel.message_encoding!r}: only zenoh-robot's raw channels "
                              "and ROS 2 cdr channels are played")
        return None

    def _refuse(self, rec: Record, why: str) -> None:
        schema = f", schema {rec.schema.encoding} {rec.schema.name}" if rec.schema is not None else ""
        label = f"{rec.channel.topic} ({rec.channel.message_encoding}{schema})"
        self.counters.unplayable[label] = why
        self._on_unplayable(f"cannot play {label}: {why}")

    def _prepare_raw(self, rec: Record, loop: int) -> Callable[[], str] | None:
        topic = rec.channel.metadata.get("zr.topic", "")
        if self.topics is not None and topic not in self.topics:
            self.counters.skipped += 1
            return None
        try:
            data = unwrap_envelope(rec.message.data)
            env = ENVELOPE.unpack(data)
        except (MalformedSample, ValueError):
            self.counters.malformed += 1
            return None
        entry = self._publisher(rec, env.publisher_id)
        if entry is None:
            self.counters.skipped += 1
            return None
        zpub, qos, type_hash = entry
        pid = loop_publisher_id(env.publisher_id, loop)
        self._announce(topic, env.type_name, env.type_hash or type_hash, qos, pid)

        def send() -> str:
            out = data
            if self.restamp or pid != env.publisher_id:
                out = ENVELOPE.pack(env._replace(publisher_id=pid,
                                                 stamp_ns=time.time_ns() if self.restamp else env.stamp_ns))
            zpub.put(out)
            return topic
        return send

    def _prepare_cdr(self, rec: Record) -> Callable[[], str] | None:
        cid = rec.channel.id
        if cid not in self._senders:
            if self.topics is not None and "/" + rec.channel.topic.strip("/") not in self.topics:
                self.counters.skipped += 1
                return None
            self._senders[cid] = self._ros2_sender(rec) if len(self._senders) < MAX_PUBLISHERS else None
        sender = self._senders[cid]
        if sender is None:
            self.counters.skipped += 1
            return None
        payload, stamp = bytes(rec.message.data), rec.message.publish_time

        def send() -> str:
            sender.put(payload, time.time_ns() if self.restamp or not stamp else stamp)
            self.counters.ros2_published += 1
            return sender.channel.topic
        return send

    def _ros2_sender(self, rec: Record) -> Ros2Sender | None:
        """The channel's publisher, once its first message decodes as its type; None (reported) if it cannot be."""
        try:
            channel = describe(rec.channel, rec.schema)
            if channel.codec is not None:
                try:
                    channel.codec.deserialize(rec.message.data, cut_trailing=True)
                except Exception as exc:    # rosbags raises several kinds for bytes that are not this type
                    raise Unplayable(f"its first message is not {channel.type_name} CDR "
                                     f"({type(exc).__name__}: {exc})") from None
        except Unplayable as why:
            self._refuse(rec, str(why))
            return None
        if self._ros2 is None:
            self._ros2 = ros2_wire()
        if self._ros2_node_token is None and self.node.wire is not self._ros2:
            # A node of another format has no ROS 2 node token: ROS 2 graphs list the player as a node too.
            self._ros2_node_token = self.node.session.liveliness().declare_token(node_token(self.node, self._ros2))
        return Ros2Sender(self.node, self._ros2, channel, secrets.randbits(63) or 1)

    def close(self) -> None:
        for sender in self._senders.values():
            if sender is not None:
                sender.close()
        self._senders.clear()
        handles = [*self._tokens.values(), *(p for p, _, _ in self._pubs.values())]
        if self._ros2_node_token is not None:
            handles.append(self._ros2_node_token)
            self._ros2_node_token = None
        for handle in handles:
            try:
                handle.undeclare()
            except Exception:
                pass
        self._tokens.clear()
        self._pubs.clear()
