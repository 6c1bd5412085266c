"""The tools' receive path: hear every publisher of a topic, decoded when the type is known here.

``open_reader`` waits for the topic's publishers, requests a QoS all of them serve, and
hands each sample to ``deliver(value, received_ns, size_bytes)`` on the node's executor.
A type this process does not know (or knows in another version) arrives as a
:class:`RawSample`. A sliced image stream (``ImageSlice``) arrives as one :class:`Frame`
per image, so ``hz``, ``bw`` and ``echo`` speak of images, not slices.

Samples arrive through the library's raw subscription mode (``raw=True``): the tools
keep no receive path of their own.
"""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from zenoh_robot.message import Message, type_support

from .common import is_ros2, load_msg_file, lookup_type, ros2_lookup
from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.graph import TopicEndpointInfo
    from zenoh_robot.node import Node
    from zenoh_robot.qos import QoSProfile

READER_DEPTH = 100
SLICE_TYPE = "zenoh_robot/ImageSlice"
MAX_OPEN_FRAMES = 8            # frames being assembled at once; older ones are given up


@dataclass(frozen=True)
class RawSample:
    """A sample of a type this process does not know (or knows in another version)."""
    type_name: str
    body: Any


@dataclass(frozen=True)
class Frame:
    """One image of a sliced image stream, as the tools count and show it."""
    seq: int
    stamp_ns: int
    width: int
    height: int
    encoding: str
    slices_received: int
    slice_count: int
    data_bytes: int

    def to_dict(self) -> dict[str, Any]:
        return {"header": {"seq": self.seq, "stamp": self.stamp_ns}, "height": self.height, "width": self.width,
                "encoding": self.encoding, "slices": f"{self.slices_received}/{self.slice_count}",
                "data": f"<{self.data_bytes} bytes of JPEG>"}


Deliver = Callable[[Any, int, int], None]     # (Message | RawSample | Frame, received ns, wire bytes)


def adapted_qos(publishers: list["TopicEndpointInfo"]) -> "QoSProfile":
    """A request every publisher can serve (ros2 topic echo's choice), so nothing is blocked."""
    from zenoh_robot.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    keeps = bool(publishers) and all(p.qos_profile.durability is DurabilityPolicy.TRANSIENT_LOCAL
                                     for p in publishers)
    return QoSProfile(ReliabilityPolicy.BEST_EFFORT,
                      DurabilityPolicy.TRANSIENT_LOCAL if keeps else DurabilityPolicy.VOLATILE,
                      HistoryPolicy.KEEP_LAST, READER_DEPTH)


def known_topics(node: "Node") -> list[str]:
    return [name for name, _types in node.get_topic_names_and_types()]


def wait_for_publishers(node: "Node", key: str, deadline: float | None) -> list["TopicEndpointInfo"]:
    node.refresh_graph(1.0)
    announced: str | None = None
    while True:
        since = node.graph.changes
        pubs = node.get_publishers_info_by_topic("/" + key)
        if pubs:
            return pubs
        # Said again when what is known changes (subscriptions of the topic seen after the first line): the
        # graph of a loaded network fills in over seconds, and the line must not stay wrong.
        hint = _did_you_mean(node, key)
        if hint != announced:
            print(f"waiting for /{key}...{hint}", file=sys.stderr, flush=True)
            announced = hint
        wait = 0.5 if deadline is None else min(0.5, deadline - time.monotonic())
        if wait <= 0:
            raise CliError(f"topic /{key} did not appear (no publisher) before --duration ran out"
                           + _did_you_mean(node, key))
        node.graph.wait_for_change(since, wait)


def _did_you_mean(node: "Node", key: str) -> str:
    from .common import did_you_mean
    if node.get_subscriptions_info_by_topic("/" + key):
        return " (only subscriptions so far)"
    return did_you_mean("/" + key, known_topics(node))


def choose_type(key: str, pubs: list["TopicEndpointInfo"], wanted: type | None) -> tuple[str, set[str]]:
    """The type name to read and the hashes its publishers send."""
    types = sorted({p.topic_type for p in pubs})
    if wanted is not None:
        name = type_support(wanted).name
        if name not in types:
            short = [t for t in types if t.rsplit("/", 1)[-1] == name.rsplit("/", 1)[-1]]
            if not short:
                raise CliError(f"/{key} carries {', '.join(types)}, not {name}")
            name = short[0]
    elif len(types) > 1:
        raise CliError(f"/{key} carries several types ({', '.join(types)}); choose one with --type")
    else:
        name = types[0]
    return name, {p.topic_type_hash for p in pubs if p.topic_type == name}


def _local_type(type_name: str, hashes: set[str], msg_file: str | None) -> type[Message] | None:
    """The class for these samples, None when unknown here or of another version."""
    if msg_file:
        # Named as the publishers name it, so the hash can match theirs.
        package = type_name.rsplit("/", 1)[0] if "/" in type_name else "msg"
        cls = load_msg_file(msg_file, package=package)
    else:
        try:
            cls = lookup_type(type_name)
        except CliError:
            print(f"{type_name} is not registered here: reading raw field values (give its .msg with --msg)",
                  file=sys.stderr, flush=True)
            return None
    ts = type_support(cls)
    if ts.name != type_name or hashes != {ts.hash}:
        print(f"{type_name} here ({ts.name}, hash {ts.hash}) differs from the publishers' "
              f"({', '.join(sorted(hashes))}): reading raw field values", file=sys.stderr, flush=True)
        return None
    return cls


class FrameAssembler:
    """Slices in, one :class:`Frame` out per image: when its last slice arrives, or when a
    newer frame starts (a slice was lost). Bounded: at most MAX_OPEN_FRAMES at once."""

    def __init__(self, deliver: Deliver) -> None:
        self._deliver = deliver
        self._open: dict[int, list[Any]] = {}    # frame -> [first slice, indices seen, bytes, last received]

    def add(self, msg: Any, received_ns: int, size: int) -> None:
        seq = int(msg.frame)    # the transport's frame counter; header.seq is the user's
        entry = self._open.get(seq)
        if entry is None:
            for old in sorted(s for s in self._open if s < seq):
                self._emit(old)
            entry = self._open[seq] = [msg, set(), 0, received_ns]
            while len(self._open) > MAX_OPEN_FRAMES:
                self._emit(min(self._open))
        entry[1].add(int(msg.index))
        entry[2] += size
        entry[3] = received_ns
        if len(entry[1]) >= max(int(msg.count), 1):
            self._emit(seq)

    def _emit(self, seq: int) -> None:
        first, seen, size, received = self._open.pop(seq)
        self._deliver(Frame(int(first.header.seq), int(first.header.stamp), int(first.width), int(first.height),
                            str(first.encoding),
                            len(seen), int(first.count), size), received, size)


def shown_type(type_name: str) -> str:
    """The type a tool shows for a topic: a sliced image stream is a stream of images."""
    return f"sensor_msgs/Image (as {type_name})" if type_name == SLICE_TYPE else type_name


def open_reader(node: "Node", key: str, wanted_type: str | None, deadline: float | None,
                deliver: Deliver, qos: "QoSProfile | None" = None, msg_file: str | None = None,
                frames: bool = True) -> str:
    """Wait for the topic's publishers, then subscribe; returns the type name read."""
    pubs = wait_for_publishers(node, key, deadline)
    ros2 = is_ros2(node)
    wanted = None
    if msg_file:
        wanted = load_msg_file(msg_file)
    elif wanted_type:
        wanted = lookup_type(wanted_type, ros2)
    type_name, hashes = choose_type(key, pubs, wanted)
    qos = qos or adapted_qos(pubs)
    if ros2:
        _open_ros2(node, key, type_name, hashes, deliver, qos)
        return type_name
    cls = _local_type(type_name, hashes, msg_file)
    decode = type_support(cls).decode if cls is not None else None
    sink: Callable[[Any, int, int], None] = deliver
    if frames and cls is not None and type_name == SLICE_TYPE:
        sink = FrameAssembler(deliver).add

    def on_raw(raw: Any, info: Any) -> None:
        if raw.type_name != type_name:
            return     # another type on the same key (--type chose one)
        value: Any = RawSample(raw.type_name, raw.fields)
        if decode is not None and raw.type_hash == type_support(cls).hash:
            try:
                value = decode(raw.fields)
            except (TypeError, ValueError):
                value = RawSample(raw.type_name, raw.fields)
        if isinstance(value, RawSample):
            deliver(value, info.received_stamp_ns, len(raw.data))
        else:
            sink(value, info.received_stamp_ns, len(raw.data))

    # The library's raw mode: QoS, bounded queue, deduplication and counters as for any
    # subscription, without needing the type here.
    node.create_subscription(None, "/" + key, on_raw, qos, raw=True)
    return type_name


def _open_ros2(node: "Node", key: str, type_name: str, hashes: set[str], deliver: Deliver,
               qos: "QoSProfile") -> None:
    """A ROS 2 topic: CDR says nothing of its type, so the type is the graph's (its publishers'
    tokens), made here from its definition and subscribed to typed; the hash must be theirs (the
    data key carries it: another version would simply never arrive)."""
    from zenoh_robot.ros2 import cdr_codec

    cls = ros2_lookup(type_name)
    ts = type_support(cls)
    if hashes - {ts.hash}:
        raise CliError(f"/{key}: {type_name} here has hash {ts.hash}, its publishers send "
                       f"{', '.join(sorted(hashes))} (another version of the type)")
    serialize = cdr_codec(cls).serialize

    def on_msg(msg: Any, info: Any) -> None:
        deliver(msg, info.received_stamp_ns, len(serialize(ts.encode(msg))))

    node.create_subscription(cls, "/" + key, on_msg, qos)
