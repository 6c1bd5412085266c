"""Record zenoh-robot topics into an MCAP flight log that Foxglove / Lichtblick open as they are.

Per topic (and message type) the file holds:

- ``<topic>``: every sample as JSON, schema = JSON schema of the message fields
  (``raw_fields`` when the type is not known here), deduplicated like a subscription;
- ``/_zr/raw<topic>``: the wire bytes exactly as they arrived, each in a one-field protobuf
  message Foxglove decodes (``zenoh_robot.RawEnvelope``, encodings.py; repeated copies that
  brought nothing new are left out), one channel per original publisher with its type, hash,
  id and QoS in the channel metadata, so ``bag play`` republishes them bit-exact, each
  publisher with its own QoS;
- on a ROS 2 node (``bag record --ros2``), a ROS 2 topic is one ``cdr`` channel per type with
  its ``ros2msg`` schema (the full definition), the payloads as they arrived, the publisher's type
  hash and QoS in the channel metadata: Foxglove, ``ros2 bag`` and rosbags read it as a rosbag2 MCAP,
  and ``bag play`` puts it back on the ROS 2 wire (play_ros2.py);
- foxglove.* views (``<topic>/fix``, ``<topic>/pose``, ``/tf``, ``<topic>/image``), see schemas.py.

Image slices and FEC shares (``zenoh_robot/ImageSlice``, ``ImageShare``) get no JSON channel
unless ``slice_json``: as JSON their JPEG bytes would be base64 (a third larger, and the bulk
of the file) while Foxglove shows the rebuilt ``<topic>/image`` view and replay uses the raw
channel.

``log_time`` is when the sample reached the recorder, ``publish_time`` its source stamp.
The topics are raw subscriptions of the node (see tap.py): their callbacks only queue the
samples (bounded; overflow is dropped and counted); one writer thread decodes and writes.
Chunks are closed at least every ``flush_period`` so a recorder killed mid-flight loses at
most that much: the file still reads up to its last chunk (see ``info.iter_records``).
A raw record's ``publish_time``/``sequence`` are those of the first new sample its envelope brought.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcap.writer import CompressionType, Writer

from zenoh_robot.graph import EndpointType, encode_qos

from . import encodings, schemas
from .tap import MAX_QUEUE_BYTES, Tap, TapSample

if TYPE_CHECKING:
    from zenoh_robot.node import Node

log = logging.getLogger("zenoh_robot.bag")

PROFILE = "zenoh-robot"
MAX_CHANNELS = 4096
SUMMARY_NAME = "zenoh_robot.recording"
BULK_TYPES = schemas.BULK_TYPES


@dataclass
class RecorderCounters:
    written: int = 0             # JSON messages written (after deduplication)
    raw_written: int = 0
    views_written: int = 0
    channels_refused: int = 0    # beyond MAX_CHANNELS
    bulk_not_json: int = 0       # image slices kept raw and as views only (slice_json False)
    cdr_written: int = 0         # ROS 2 samples (a recorder on the ROS 2 wire)
    untyped: int = 0             # ROS 2 samples whose publisher's type the graph did not (yet) tell
    no_definition: int = 0       # ROS 2 samples of a type this process has no definition of (no schema)
    per_topic: dict[str, int] = field(default_factory=dict)


class BagRecorder(Tap):
    """``with BagRecorder(node, "flight.mcap", topics=None): node.spin(...)`` (None: every topic)."""

    def __init__(self, node: "Node", path: str | Path, topics: list[str] | None = None, *,
                 views: bool = True, raw: bool = True, chunk_size: int = 1 << 20, flush_period: float = 1.0,
                 max_queue_bytes: int = MAX_QUEUE_BYTES, compression: str = "zstd", slice_json: bool = False,
                 exclude: str | None = None) -> None:
        super().__init__(node, topics, max_queue_bytes=max_queue_bytes, name="bag-writer", exclude=exclude)
        self.path = Path(path)
        self.views = views
        self.raw = raw
        self.slice_json = slice_json
        self.tick_period = flush_period
        self.counters = RecorderCounters()
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self._view_maker = schemas.ViewMaker()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size,
                              compression=CompressionType.ZSTD if compression == "zstd" else CompressionType.NONE)
        self._writer.start(profile=PROFILE, library="zenoh-robot bag")
        self.first_log_ns: int | None = None
        self.last_log_ns: int | None = None
        # name -> {key: value}: written as MCAP metadata records at the end (e.g. the GCS's summary)
        self.metadata: dict[str, dict[str, str]] = {}

    def __enter__(self) -> "BagRecorder":
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def tick(self) -> None:
        self._writer.flush()  # type: ignore[no-untyped-call]  # close the chunk: a recorder killed mid-flight loses at most this period

    def finish(self) -> None:
        """Summary metadata, index and footer (on the worker thread, after the last sample)."""
        c = self.counters
        summary = {k: str(v) for k, v in vars(c).items() if k != "per_topic"}
        summary.update({k: str(v) for k, v in vars(self.tap_counters).items()})
        summary["topics"] = json.dumps(c.per_topic)
        self._writer.add_metadata(SUMMARY_NAME, summary)
        for name, values in self.metadata.items():
            self._writer.add_metadata(name, {str(k): str(v) for k, v in values.items()})
        self._writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
        self._file.close()

    def _schema_id(self, name: str, encoding: str, data: bytes) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._schemas[name] = self._writer.register_schema(name, encoding, data)
        return sid

    def _channel(self, topic: str, kind: str, type_name: str, make: Any) -> int | None:
        key = (topic, kind, type_name)
        cid = self._channels.get(key)
        if cid is None:
            if len(self._channels) >= MAX_CHANNELS:
                self.counters.channels_refused += 1
                return None
            cid = self._channels[key] = make()
        return cid

    def handle(self, sample: TapSample) -> None:
        topic, received_ns = sample.topic, sample.received_ns
        self.first_log_ns = received_ns if self.first_log_ns is None else self.first_log_ns
        self.last_log_ns = received_ns
        if not sample.type_name and self.node.wire.name == "ros2":   # CDR: the type is in the graph
            self._handle_cdr(sample)
            return
        if self.raw and sample.data is not None:
            cid = self._channel(topic, "raw", f"{sample.type_name}#{sample.publisher_id:x}",
                                lambda: self._raw_channel(topic, sample))
            if cid is not None:
                self._writer.add_message(cid, received_ns, encodings.wrap_envelope(sample.data), sample.stamp_ns,
                                         sample.seq & 0xFFFFFFFF)
                self.counters.raw_written += 1
        cls = schemas.local_type(sample.type_name, sample.type_hash)
        json_wanted = self.slice_json or sample.type_name not in BULK_TYPES
        cid = self._channel(topic, "json", sample.type_name, lambda: self._json_channel(topic, sample, cls)) \
            if json_wanted else None
        decoded = schemas.decode_body(cls, sample.fields, with_data=json_wanted)
        if cid is not None:
            self._writer.add_message(cid, received_ns, schemas.encode_json(decoded.data), sample.stamp_ns,
                                     sample.seq & 0xFFFFFFFF)
            self.counters.written += 1
            self.counters.per_topic[topic] = self.counters.per_topic.get(topic, 0) + 1
        elif not json_wanted:
            self.counters.bulk_not_json += 1
        if self.views:
            for view in self._view_maker.views(topic, sample.type_name, decoded, sample.stamp_ns):
                self._write_view(view, received_ns, sample.stamp_ns)

    def _handle_cdr(self, sample: TapSample) -> None:
        pub = self.ros2_publisher(sample, self.counters)
        if pub is None:
            return
        try:
            cid = self._channel(sample.topic, "cdr", pub.topic_type, lambda: self._cdr_channel(sample.topic, pub))
        except KeyError:
            self.no_ros2_definition(pub.topic_type, sample.topic, self.counters,
                                    "not recorded (its schema could not be written)")
            return
        if cid is None:
            return
        payload = sample.data if sample.data is not None else sample.fields
        self._writer.add_message(cid, sample.received_ns, bytes(payload), sample.stamp_ns, sample.seq & 0xFFFFFFFF)
        self.counters.cdr_written += 1
        self.counters.per_topic[sample.topic] = self.counters.per_topic.get(sample.topic, 0) + 1

    def _cdr_channel(self, topic: str, pub: Any) -> int:
        sid = self._schema_id(pub.topic_type, encodings.ROS2MSG, encodings.ros2msg_schema(pub.topic_type))
        # The publisher's QoS too: bag play offers the same (ros2 bag keeps it as offered_qos_profiles)
        return self._writer.register_channel(topic, encodings.CDR, sid, {"zr.type": pub.topic_type,
                                                                         "zr.hash": pub.topic_type_hash,
                                                                         "zr.qos": encode_qos(pub.qos_profile)})

    def _write_view(self, view: schemas.View, received_ns: int, stamp_ns: int) -> None:
        schema = view.message.get_schema()
        name = schema.name
        cid = self._channel(view.topic, "view", name, lambda: self._writer.register_channel(
            view.topic, "protobuf", self._schema_id(name, schema.encoding, bytes(schema.data))))
        if cid is not None:
            self._writer.add_message(cid, received_ns, bytes(view.message.encode()), stamp_ns)
            self.counters.views_written += 1

    def _json_channel(self, topic: str, env: TapSample, cls: Any) -> int:
        schema = schemas.object_schema(cls) if cls is not None else schemas.RAW_FIELDS_SCHEMA
        name = env.type_name if cls is not None else f"{env.type_name}#raw"
        sid = self._schema_id(name, schemas.JSON_SCHEMA, json.dumps(schema).encode())
        return self._writer.register_channel(topic, "json", sid, {"zr.type": env.type_name,
                                                                  "zr.hash": env.type_hash})

    def _raw_channel(self, topic: str, env: TapSample) -> int:
        pubs = [p for p in self.node.graph.endpoints(topic[1:], EndpointType.PUBLISHER)
                if p.topic_type == env.type_name]
        # This publisher's own QoS; one of the same type when its announcement has not arrived yet
        pubs.sort(key=lambda p: p.endpoint_gid != env.publisher_id)
        meta = {"zr.topic": topic, "zr.type": env.type_name, "zr.hash": env.type_hash,
                "zr.publisher": f"{env.publisher_id:x}"}
        if pubs:
            meta["zr.qos"] = encode_qos(pubs[0].qos_profile)
        sid = self._schema_id(encodings.RAW_ENVELOPE_SCHEMA, encodings.PROTOBUF, encodings.RAW_ENVELOPE_DESCRIPTOR)
        return self._writer.register_channel(schemas.raw_topic(topic), encodings.PROTOBUF, sid, meta)
