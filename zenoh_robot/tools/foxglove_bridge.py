"""A live view of every topic in Foxglove / Lichtblick: the Foxglove WebSocket protocol, served by foxglove-sdk.

``zenoh-robot foxglove --port 8765``, then open ``ws://127.0.0.1:8765`` in Foxglove
("Open connection" -> Foxglove WebSocket). Every topic found through the graph is
advertised as it appears: as JSON with a JSON schema from its message fields (plots,
raw messages), plus the foxglove.* views of tools/bag/schemas.py (map fix, 3D pose and
``/tf`` of each vehicle, setpoint poses, camera frames as CompressedImage/RawImage).
The same mapping writes the MCAP flight logs, so a recording looks like the live view
(image slices, too, are sent as the reassembled frames only unless ``slice_json``).

On a node on the ROS 2 wire (``zenoh-robot foxglove --ros2``), each ROS 2 topic (a companion's
``--ros2-topics`` streams, PX4's ``/fmu/*``) is a ``cdr`` channel whose schema is its type's full
``ros2msg`` definition, as rosbag2 writes one (bag/encodings.py): Foxglove decodes the payloads as
they arrived, natively. The type comes from the publisher's token; a sample whose publisher is not in
the graph yet, or whose type this process has no definition of, is counted and not sent.

The server binds 127.0.0.1 unless told otherwise: a bridge exposes every topic, so
reaching it from another machine is a decision (``--host``), not a default.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .bag import encodings, schemas
from .bag.tap import MAX_QUEUE_BYTES, Tap, TapSample

if TYPE_CHECKING:
    from zenoh_robot.node import Node

log = logging.getLogger("zenoh_robot.foxglove")
MAX_CHANNELS = 4096


@dataclass
class BridgeCounters:
    forwarded: int = 0           # JSON messages logged
    views: int = 0               # foxglove.* messages logged
    cdr: int = 0                 # ROS 2 messages logged (a bridge on the ROS 2 wire)
    untyped: int = 0             # ROS 2 samples whose publisher's type the graph did not (yet) tell
    no_definition: int = 0       # ROS 2 samples of a type this process has no definition of
    channels_refused: int = 0


class FoxgloveBridge(Tap):
    """``FoxgloveBridge(node, port=8765).start()``; ``close()`` stops the server too."""

    def __init__(self, node: "Node", topics: list[str] | None = None, *, host: str = "127.0.0.1",
                 port: int = 8765, max_queue_bytes: int = MAX_QUEUE_BYTES, slice_json: bool = False) -> None:
        super().__init__(node, topics, max_queue_bytes=max_queue_bytes, name="foxglove-bridge")
        self.slice_json = slice_json
        import foxglove

        self._foxglove = foxglove
        # Its own context: channels made here reach this server only, not other foxglove sinks.
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name="zenoh-robot", host=host, port=port, context=self.context)
        self.host, self.port = host, self.server.port
        self.counters = BridgeCounters()
        self._channels: dict[tuple[str, str], Any] = {}
        self._view_maker = schemas.ViewMaker()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def app_url(self) -> str:
        """Foxglove's web app opening this bridge directly."""
        return f"https://app.foxglove.dev/~/view?ds=foxglove-websocket&ds.url={self.url}"

    def finish(self) -> None:
        for ch in self._channels.values():
            try:
                ch.close()
            except Exception:
                pass
        self.server.stop()

    def _channel(self, topic: str, schema_name: str, make: Any) -> Any | None:
        key = (topic, schema_name)
        ch = self._channels.get(key)
        if ch is None:
            if len(self._channels) >= MAX_CHANNELS:
                self.counters.channels_refused += 1
                return None
            ch = self._channels[key] = make()
        return ch

    def handle(self, sample: TapSample) -> None:
        if not sample.type_name and self.node.wire.name == "ros2":    # CDR: the type is in the graph
            self._handle_cdr(sample)
            return
        topic, received_ns = sample.topic, sample.received_ns
        cls = schemas.local_type(sample.type_name, sample.type_hash)
        fx = self._foxglove

        def json_channel() -> Any:
            schema = schemas.object_schema(cls) if cls is not None else schemas.RAW_FIELDS_SCHEMA
            name = sample.type_name if cls is not None else f"{sample.type_name}#raw"
            return fx.Channel(topic, schema=fx.Schema(name=name, encoding=schemas.JSON_SCHEMA,
                                                      data=json.dumps(schema).encode()),
                              message_encoding="json", context=self.context,
                              metadata={"zr.type": sample.type_name, "zr.hash": sample.type_hash})

        json_wanted = self.slice_json or sample.type_name not in schemas.BULK_TYPES
        ch = self._channel(topic, sample.type_name, json_channel) if json_wanted else None
        decoded = schemas.decode_body(cls, sample.fields, with_data=json_wanted)
        if ch is not None:
            ch.log(schemas.encode_json(decoded.data), log_time=received_ns)
            self.counters.forwarded += 1
        for view in self._view_maker.views(topic, sample.type_name, decoded, sample.stamp_ns):
            self._log_view(view, received_ns)

    def _handle_cdr(self, sample: TapSample) -> None:
        pub = self.ros2_publisher(sample, self.counters)
        if pub is None:
            return
        type_name = pub.topic_type
        fx = self._foxglove
        try:
            ch = self._channel(sample.topic, type_name, lambda: fx.Channel(
                sample.topic, schema=fx.Schema(name=type_name, encoding=encodings.ROS2MSG,
                                               data=encodings.ros2msg_schema(type_name)),
                message_encoding=encodings.CDR, context=self.context,
                metadata={"zr.type": type_name, "zr.hash": pub.topic_type_hash}))
        except KeyError:
            self.no_ros2_definition(type_name, sample.topic, self.counters,
                                    "not shown (load its .msg with zenoh_robot.ros2.load_ros2_msg)")
            return
        if ch is not None:
            payload = sample.data if sample.data is not None else sample.fields
            ch.log(bytes(payload), log_time=sample.received_ns)
            self.counters.cdr += 1

    def _log_view(self, view: schemas.View, received_ns: int) -> None:
        schema = view.message.get_schema()
        fx = self._foxglove
        ch = self._channel(view.topic, schema.name, lambda: fx.Channel(
            view.topic, schema=schema, message_encoding="protobuf", context=self.context))
        if ch is not None:
            ch.log(bytes(view.message.encode()), log_time=received_ns)
            self.counters.views += 1


def pick_port(preferred: int = 8765) -> int:
    """``preferred`` when free on loopback, else any free port (a second demo must not fail on it)."""
    import socket
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", preferred))
            return preferred
        except OSError:
            s.bind(("127.0.0.1", 0))
            return int(s.getsockname()[1])
