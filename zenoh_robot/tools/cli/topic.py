"""``zenoh-robot topic list|info|echo|hz|pub``: ros2 topic's tools over the graph and the wire.

TOPIC is absolute (``/uav1/setpoint``; a name without the leading ``/`` means the same).
``echo`` and ``hz`` request a QoS every publisher can serve (best effort, no deadline,
transient local only when every publisher keeps samples), as ``ros2 topic echo`` does,
so they hear a topic whatever its publishers offer.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import math
import os
import secrets
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterator

import yaml

from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.graph import TopicEndpointInfo
    from zenoh_robot.node import Node
    from zenoh_robot.qos import QoSProfile

HIDDEN_PREFIX = "_zr_"        # the CLI's own nodes: left out of list/info unless --all
READER_DEPTH = 100
REPORT_PERIOD = 1.0           # seconds between `hz` reports
GRAPH_QUIET = 0.5             # seconds without a new graph entry: discovery has settled


# -- shared with `stats` ------------------------------------------------------------------
def add_config_arg(parser: argparse.ArgumentParser) -> None:
    # SUPPRESS: given before or after the operation, a missing one never overwrites the other.
    parser.add_argument("--config", default=argparse.SUPPRESS,
                        help="Zenoh session config (YAML/JSON5) to reach the network")


def add_duration_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, metavar="S", help="exit after S seconds")


def deadline_of(args: argparse.Namespace) -> float | None:
    if args.duration is None:
        return None
    if not args.duration > 0:
        raise CliError(f"--duration must be > 0 seconds, got {args.duration:g}")
    return time.monotonic() + args.duration


def quiet_exit(fn: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Ctrl-C ends a command normally (exit 0, no traceback); so does a closed pipe (`| head`)."""
    @functools.wraps(fn)
    def wrapper(args: argparse.Namespace) -> int:
        try:
            return fn(args)
        except KeyboardInterrupt:
            return 0
        except BrokenPipeError:
            # Python would complain again flushing stdout at exit: point it at /dev/null.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
    return wrapper


@contextlib.contextmanager
def cli_node(kind: str, args: argparse.Namespace) -> Iterator["Node"]:
    """A hidden node (``_zr_<kind>_<hex>``) on the configured session, always closed."""
    from zenoh_robot.node import Node   # imported late so `zenoh-robot --help` stays fast
    from zenoh_robot.session_config import SessionConfigError

    try:
        node = Node(f"{HIDDEN_PREFIX}{kind}_{secrets.token_hex(3)}", config=getattr(args, "config", None))
    except SessionConfigError as exc:
        raise CliError(one_line(str(exc))) from None
    try:
        yield node
    finally:
        _close_uninterrupted(node)


def _close_uninterrupted(node: "Node") -> None:
    # A second Ctrl-C halfway through close() would leave the session open and exit hanging on it.
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        node.close()
    finally:
        if previous is not None:   # None: a handler not set from Python, nothing to restore
            signal.signal(signal.SIGINT, previous)


class CallbackOutput:
    """stdout for text printed from callbacks, where the executor would catch (and log) a
    closed pipe: a reader gone (`| head`) is remembered, and ends the command."""

    def __init__(self) -> None:
        self.closed = False

    def print(self, text: str) -> None:
        if self.closed:
            return
        try:
            print(text, flush=True)
        except BrokenPipeError:
            self.closed = True

    def check(self) -> None:
        if self.closed:
            raise BrokenPipeError("stdout closed")


def one_line(text: str) -> str:
    return " ".join(text.split())


def spin_until(node: "Node", done: Callable[[], bool], deadline: float | None) -> None:
    """Run the node's callbacks on this thread until ``done()`` or the deadline."""
    while not done():
        wait = 0.1
        if deadline is not None:
            wait = min(wait, deadline - time.monotonic())
            if wait <= 0:
                return
        node.spin_once(wait)


def topic_key(topic: str) -> str:
    """``/a/b`` or ``a/b`` -> the Zenoh key ``a/b`` (validated by ROS 2's name rules)."""
    from zenoh_robot.names import InvalidNameError, resolve_topic

    try:
        return resolve_topic(topic if topic.startswith("/") else "/" + topic)
    except InvalidNameError as exc:
        raise CliError(str(exc)) from None


def lookup_type(name: str) -> type:
    from zenoh_robot import msgs  # noqa: F401  registers the standard and drone types
    from zenoh_robot.message import lookup

    try:
        return lookup(name)
    except KeyError as exc:
        raise CliError(str(exc.args[0])) from None


# -- registration ---------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("topic", help="list, inspect, echo, measure and publish topics")
    add_config_arg(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    _register_list(ops)
    _register_info(ops)
    _register_echo(ops)
    _register_hz(ops)
    _register_pub(ops)
    p.set_defaults(func=run)


def _op_parser(ops: argparse._SubParsersAction, name: str, help: str) -> argparse.ArgumentParser:
    o = ops.add_parser(name, help=help)
    add_config_arg(o)
    return o


def _graph_args(o: argparse.ArgumentParser) -> None:
    o.add_argument("-v", "--verbose", dest="detail", action="store_true", help="more detail")
    o.add_argument("-a", "--all", action="store_true", help="include the CLI tools' own endpoints (_zr_ nodes)")
    o.add_argument("--timeout", type=float, default=3.0,
                   help="at most this many seconds to learn the graph (default 3)")


def _register_list(ops: argparse._SubParsersAction) -> None:
    o = _op_parser(ops, "list", "topics on the network")
    _graph_args(o)


def _register_info(ops: argparse._SubParsersAction) -> None:
    o = _op_parser(ops, "info", "a topic's type, publishers, subscriptions, QoS and their compatibility")
    o.add_argument("topic", help="absolute topic name, e.g. /uav1/setpoint")
    _graph_args(o)


def _reader_args(o: argparse.ArgumentParser) -> None:
    o.add_argument("topic", help="absolute topic name, e.g. /uav1/setpoint")
    o.add_argument("--type", help="message type, when the topic carries several")
    add_duration_arg(o)


def _register_echo(ops: argparse._SubParsersAction) -> None:
    o = _op_parser(ops, "echo", "print a topic's messages")
    _reader_args(o)
    o.add_argument("--count", type=int, metavar="N", help="exit after N messages")
    o.add_argument("--once", action="store_true", help="exit after the first message")
    o.add_argument("--no-arr", action="store_true", help="show arrays as their length only")


def _register_hz(ops: argparse._SubParsersAction) -> None:
    o = _op_parser(ops, "hz", "a topic's receive rate")
    _reader_args(o)
    o.add_argument("--window", type=int, default=10_000, metavar="N",
                   help="intervals the statistics cover (default 10000)")


def _register_pub(ops: argparse._SubParsersAction) -> None:
    o = _op_parser(ops, "pub", "publish a message")
    o.add_argument("topic", help="absolute topic name, e.g. /uav1/setpoint")
    o.add_argument("type", help="message type, e.g. std_msgs/String or Setpoint")
    o.add_argument("values", nargs="?", default="{}",
                   help="fields as YAML, e.g. '{data: hello}' ('{header: auto}' stamps the header)")
    o.add_argument("-r", "--rate", type=float, default=1.0, help="messages per second (default 1)")
    o.add_argument("-t", "--times", type=int, metavar="N", help="publish N messages, then exit")
    o.add_argument("-1", "--once", action="store_true", help="publish one message, then exit")
    o.add_argument("--qos", default="system_default", metavar="PRESET",
                   help="QoS preset (system_default, sensor_data, control, setpoint, ...)")
    o.add_argument("--max-wait", type=float, default=1.0, metavar="S",
                   help="with --once/--times: seconds to wait for a matching subscription first (default 1)")
    o.add_argument("--keep-alive", type=float, default=0.2, metavar="S",
                   help="seconds to stay up after the last message so it is delivered (default 0.2)")
    add_duration_arg(o)


@quiet_exit
def run(args: argparse.Namespace) -> int:
    return _OPS[args.op](args)


# -- list / info ------------------------------------------------------------------------------
def _endpoints(node: "Node", topic: str, show_all: bool) -> tuple[list["TopicEndpointInfo"], list["TopicEndpointInfo"]]:
    def visible(infos: list["TopicEndpointInfo"]) -> list["TopicEndpointInfo"]:
        return sorted((e for e in infos if show_all or not e.node_name.startswith(HIDDEN_PREFIX)),
                      key=lambda e: (e.node_namespace, e.node_name, e.endpoint_gid))
    return visible(node.get_publishers_info_by_topic(topic)), visible(node.get_subscriptions_info_by_topic(topic))


def discover_graph(node: "Node", timeout: float, found: Callable[[], bool] = lambda: True) -> None:
    """Learn the graph: until ``found()`` and no entry has come for GRAPH_QUIET s, at most ``timeout``.

    A fresh session returns from open once it reaches one peer; the others, and their
    entities, arrive over the next moments: a quiet spell is the sign they all have.
    """
    if not timeout > 0:
        raise CliError(f"--timeout must be > 0 seconds, got {timeout:g}")
    end = time.monotonic() + timeout
    node.refresh_graph(min(1.0, timeout))
    while True:
        since = node.graph.changes
        ready = found()
        left = end - time.monotonic()
        if left <= 0:
            return
        changed = node.graph.wait_for_change(since, min(GRAPH_QUIET if ready else 0.1, left))
        if ready and not changed:
            return


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


def _list(args: argparse.Namespace) -> int:
    with cli_node("topic", args) as node:
        discover_graph(node, args.timeout)
        for name, _types in node.get_topic_names_and_types():
            pubs, subs = _endpoints(node, name, args.all)
            if not (pubs or subs):
                continue
            if not args.detail:
                print(name)
                continue
            types = sorted({e.topic_type for e in pubs + subs})
            print(f"{name} [{', '.join(types)}] {_plural(len(pubs), 'publisher')}, "
                  f"{_plural(len(subs), 'subscription')}")
    return 0


def _info(args: argparse.Namespace) -> int:
    name = "/" + topic_key(args.topic)
    with cli_node("topic", args) as node:
        discover_graph(node, args.timeout, lambda: any(_endpoints(node, name, args.all)))
        pubs, subs = _endpoints(node, name, args.all)
        if not (pubs or subs):
            raise CliError(f"topic {name} not found: no publisher or subscription on the graph")
        pairs = [(p, s, _verdict(p, s)) for p in pubs for s in subs]
        print(f"Type: {', '.join(sorted({e.topic_type for e in pubs + subs}))}")
        print(f"Publisher count: {len(pubs)}")
        print(f"Subscription count: {len(subs)}")
        bad = sum(1 for *_, v in pairs if v.startswith("incompatible"))
        if not args.detail:
            if bad:
                print(f"QoS: {_plural(bad, 'incompatible publisher/subscription pair')} (see -v)")
            return 0
        for e in pubs + subs:
            print()
            print("\n".join(endpoint_lines(e)))
        if pairs:
            print()
            print("QoS compatibility (publisher -> subscription):")
            for p, s, verdict in pairs:
                print(f"  {_who(p)} -> {_who(s)}: {verdict}")
    return 0


def _who(e: "TopicEndpointInfo") -> str:
    return f"{e.node_namespace.rstrip('/')}/{e.node_name} [gid {e.endpoint_gid:016x}]"


def _verdict(pub: "TopicEndpointInfo", sub: "TopicEndpointInfo") -> str:
    from zenoh_robot.qos_compat import Compatibility, check_compatibility

    if pub.topic_type_hash != sub.topic_type_hash:
        return (f"incompatible (TYPE): publisher sends {pub.topic_type} ({pub.topic_type_hash}), "
                f"subscription expects {sub.topic_type} ({sub.topic_type_hash})")
    v = check_compatibility(pub.qos_profile, sub.qos_profile)
    if v.compatibility is Compatibility.OK:
        return "compatible"
    word = "incompatible" if v.compatibility is Compatibility.ERROR else "warning"
    return f"{word} ({v.policy.name}): {v.reason}"


def endpoint_lines(e: "TopicEndpointInfo") -> list[str]:
    return [f"Node name: {e.node_name}", f"Node namespace: {e.node_namespace}", f"Topic type: {e.topic_type}",
            f"Topic type hash: {e.topic_type_hash}", f"Endpoint type: {e.endpoint_type.name}",
            f"GID: {e.endpoint_gid:016x}", "QoS profile:", *("  " + line for line in qos_lines(e.qos_profile))]


def qos_lines(q: "QoSProfile") -> list[str]:
    from zenoh_robot.qos import HistoryPolicy
    from zenoh_robot.qos_compat import format_duration as _seconds

    history = f"{q.history.name} ({q.depth})" if q.history is HistoryPolicy.KEEP_LAST else q.history.name
    lines = [f"Reliability: {q.reliability.name}", f"Durability: {q.durability.name}",
             f"History (depth): {history}", f"Deadline: {_seconds(q.deadline)}",
             f"Lifespan: {_seconds(q.lifespan)}", f"Liveliness: {q.liveliness.name}",
             f"Liveliness lease duration: {_seconds(q.liveliness_lease_duration)}",
             f"Priority: {q.priority.name}"]
    if q.express or q.redundancy or q.repeat:
        lines.append(f"Express: {str(q.express).lower()}, redundancy: {q.redundancy}, repeat: {q.repeat}")
    return lines


# -- echo / hz: a reader that hears every publisher ---------------------------------------------
@dataclass(frozen=True)
class RawSample:
    """A sample of a type this process does not know (or knows in another version)."""
    type_name: str
    body: Any


Deliver = Callable[[Any, int], None]     # (Message or RawSample, received ns), on the executor


def adapted_qos(publishers: list["TopicEndpointInfo"]) -> "QoSProfile":
    """A request every publisher can serve (ros2 topic echo's choice), so nothing is blocked."""
    from zenoh_robot.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    keeps = bool(publishers) and all(p.qos_profile.durability is DurabilityPolicy.TRANSIENT_LOCAL
                                     for p in publishers)
    return QoSProfile(ReliabilityPolicy.BEST_EFFORT,
                      DurabilityPolicy.TRANSIENT_LOCAL if keeps else DurabilityPolicy.VOLATILE,
                      HistoryPolicy.KEEP_LAST, READER_DEPTH)


def wait_for_publishers(node: "Node", key: str, deadline: float | None) -> list["TopicEndpointInfo"]:
    node.refresh_graph(1.0)
    announced = False
    while True:
        since = node.graph.changes
        pubs = node.get_publishers_info_by_topic("/" + key)
        if pubs:
            return pubs
        if not announced:
            print(f"waiting for /{key}...", file=sys.stderr, flush=True)
            announced = True
        wait = 0.5 if deadline is None else min(0.5, deadline - time.monotonic())
        if wait <= 0:
            raise CliError(f"topic /{key} did not appear (no publisher) before --duration ran out")
        node.graph.wait_for_change(since, wait)


def _choose_type(key: str, pubs: list["TopicEndpointInfo"], wanted: str | None) -> tuple[str, set[str]]:
    """The type name to read and the hashes its publishers send."""
    types = sorted({p.topic_type for p in pubs})
    if wanted:
        name = lookup_type(wanted)._type_name
        if name not in types:
            raise CliError(f"/{key} carries {', '.join(types)}, not {name}")
    elif len(types) > 1:
        raise CliError(f"/{key} carries several types ({', '.join(types)}); choose one with --type")
    else:
        name = types[0]
    return name, {p.topic_type_hash for p in pubs if p.topic_type == name}


def _local_type(type_name: str, hashes: set[str]) -> type | None:
    """The registered class for these samples, None when unknown here or of another version."""
    try:
        cls = lookup_type(type_name)
    except CliError:
        print(f"{type_name} is not registered here: reading raw field values", file=sys.stderr, flush=True)
        return None
    if cls._type_name != type_name or hashes != {cls._type_hash}:
        print(f"{type_name} here differs from the publishers' (hash {cls._type_hash} vs "
              f"{', '.join(sorted(hashes))}): reading raw field values", file=sys.stderr, flush=True)
        return None
    return cls


class RawReader:
    """Samples of an unknown type: envelope unpacked, repeats dropped, handed to the executor."""

    def __init__(self, node: "Node", key: str, qos: "QoSProfile", deliver: Deliver) -> None:
        from zenoh_robot.qos_mapping import declare_subscriber
        from zenoh_robot._wire.redundancy import Deduplicator

        self._executor = node.executor
        self._deliver = deliver
        self._dedup = Deduplicator()
        self.malformed = 0
        self._zsub = declare_subscriber(node.session, key, qos, self._on_sample)

    def _on_sample(self, sample: Any) -> None:   # Zenoh's thread: hand on, nothing more
        data, now = sample.payload.to_bytes(), time.time_ns()
        self._executor.call_soon(lambda: self._handle(data, now))

    def _handle(self, data: bytes, received_ns: int) -> None:
        from zenoh_robot._wire import envelope

        try:
            env = envelope.unpack(data)
        except envelope.MalformedSample:
            self.malformed += 1
            return
        for _seq, _stamp, body in self._dedup.fresh(env.publisher_id, env.seq, env.stamp_ns, env.body, env.extra):
            self._deliver(RawSample(env.type_name, body), received_ns)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._zsub.undeclare()


def open_reader(node: "Node", key: str, wanted_type: str | None, deadline: float | None,
                deliver: Deliver) -> None:
    """Wait for the topic's publishers, then subscribe with a QoS all of them serve."""
    pubs = wait_for_publishers(node, key, deadline)
    type_name, hashes = _choose_type(key, pubs, wanted_type)
    qos = adapted_qos(pubs)
    cls = _local_type(type_name, hashes)
    if cls is None:
        reader = RawReader(node, key, qos, deliver)
        node.add_on_close(reader.close)
        return
    node.create_subscription(cls, "/" + key, lambda msg, info: deliver(msg, info.received_stamp_ns), qos)


def _plain(value: Any, no_arr: bool) -> Any:
    """Message data as YAML-safe values: bytes as their size, arrays as their length with --no-arr."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return f"<{len(value)} bytes>"
    if isinstance(value, dict):
        return {k: _plain(v, no_arr) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return f"<array, length: {len(value)}>" if no_arr else [_plain(v, no_arr) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)     # anything else (a numpy scalar, say) would stop safe_dump


def render_sample(value: Any, no_arr: bool = False) -> str:
    if isinstance(value, RawSample):
        body = value.body
        fields = [_plain(v, no_arr) for v in body] if isinstance(body, list) else _plain(body, no_arr)
        data = {"type": value.type_name, "raw_fields": fields}   # in declaration order
    else:
        data = _plain(value.to_dict(), no_arr)
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, default_flow_style=False).rstrip()


def _echo(args: argparse.Namespace) -> int:
    key = topic_key(args.topic)
    deadline = deadline_of(args)
    limit = 1 if args.once else args.count
    if limit is not None and limit < 1:
        raise CliError(f"--count must be >= 1, got {limit}")
    out = CallbackOutput()
    printed = 0

    def show(value: Any, _received_ns: int) -> None:
        nonlocal printed
        if limit is not None and printed >= limit:
            return     # samples already queued when the count is reached
        out.print(f"{render_sample(value, args.no_arr)}\n---")
        printed += 1

    with cli_node("topic", args) as node:
        open_reader(node, key, args.type, deadline, show)
        spin_until(node, lambda: out.closed or (limit is not None and printed >= limit), deadline)
    out.check()
    return 0


@dataclass
class RateWindow:
    """Arrival times spanning the last ``size`` intervals, and ros2 topic hz's statistics over them."""
    stamps: deque[int]
    total: int = 0

    @classmethod
    def of(cls, size: int) -> "RateWindow":
        return cls(deque(maxlen=size + 1))

    def add(self, received_ns: int) -> None:
        self.stamps.append(received_ns)
        self.total += 1

    def report(self) -> str | None:
        s = list(self.stamps)
        intervals = [(b - a) / 1e9 for a, b in zip(s, s[1:])]
        if not intervals:
            return None
        mean = sum(intervals) / len(intervals)
        std = math.sqrt(sum((x - mean) ** 2 for x in intervals) / len(intervals))
        rate = 1.0 / mean if mean > 0 else float("inf")
        return (f"average rate: {rate:.3f}\n\tmin: {min(intervals):.3f}s max: {max(intervals):.3f}s "
                f"std dev: {std:.5f}s window: {len(intervals)}")


def _hz(args: argparse.Namespace) -> int:
    key = topic_key(args.topic)
    deadline = deadline_of(args)
    if args.window < 1:
        raise CliError(f"--window must be >= 1, got {args.window}")
    window = RateWindow.of(args.window)
    out = CallbackOutput()
    reported = 0

    def report() -> None:
        nonlocal reported
        if window.total == reported:
            if reported:
                out.print("no new messages")
            return
        reported = window.total
        text = window.report()
        if text:
            out.print(text)

    with cli_node("topic", args) as node:
        open_reader(node, key, args.type, deadline, lambda _value, received_ns: window.add(received_ns))
        node.create_timer(REPORT_PERIOD, report)
        spin_until(node, lambda: out.closed, deadline)
    out.check()
    return 0


# -- pub ----------------------------------------------------------------------------------------
_INTEGERS = frozenset({"byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"})


def parse_values(text: str) -> dict[str, Any]:
    try:
        data = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise CliError(one_line(f"values are not valid YAML: {problem}{where}")) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise CliError(f"values must be a YAML mapping of field names to values, e.g. '{{data: hello}}'; "
                       f"got {one_line(text)!r}")
    return data


def _coerce_scalar(base: str, value: Any, where: str) -> Any:
    if base == "bool" and isinstance(value, bool):
        return value
    if base in _INTEGERS and isinstance(value, int) and not isinstance(value, bool):
        return value
    if base in ("float32", "float64") and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if base in ("string", "wstring") and isinstance(value, str):
        return value
    raise CliError(f"{where}: expected {base}, got {type(value).__name__} {value!r}")


def _coerce_field(spec: Any, value: Any, where: str) -> Any:
    """YAML's value as the field's Python type, so receivers never meet a str for a float."""
    if spec.is_bytes:
        if isinstance(value, (bytes, bytearray)):
            return bytes(value)
        if isinstance(value, list) and all(isinstance(v, int) and 0 <= v <= 255 for v in value):
            return bytes(value)
        raise CliError(f"{where}: expected a list of bytes (0..255), got {value!r}")
    if spec.array is not None:
        if not isinstance(value, (list, tuple)):
            raise CliError(f"{where}: expected a list ({spec.ros_type()}), got {value!r}")
        return [_coerce_scalar(spec.base, v, f"{where}[{i}]") for i, v in enumerate(value)]
    return _coerce_scalar(spec.base, value, where)


def check_fields(msg: Any) -> None:
    for spec in msg._fields_spec:
        value = getattr(msg, spec.name)
        where = f"{msg._type_name}.{spec.name}"
        if spec.is_message:
            for item in (value if spec.array is not None else [value]):
                check_fields(item)
        else:
            setattr(msg, spec.name, _coerce_field(spec, value, where))


def build_message(cls: type, data: dict[str, Any]) -> tuple[Any, bool]:
    """The message, and whether its header is to be stamped at each publish (``header: auto``)."""
    auto_header = data.get("header") == "auto" and any(s.name == "header" for s in cls._fields_spec)
    if auto_header:
        data = {k: v for k, v in data.items() if k != "header"}
    try:
        msg = cls.from_dict(data)
    except (TypeError, ValueError) as exc:
        raise CliError(one_line(str(exc))) from None
    check_fields(msg)
    try:
        cls._to_wire(msg)   # the checks only encoding makes (a fixed array's length), before any session
    except (TypeError, ValueError) as exc:
        raise CliError(one_line(str(exc))) from None
    return msg, auto_header


@dataclass
class PubPlan:
    rate: float
    times: int | None
    max_wait: float
    keep_alive: float


def _pub_plan(args: argparse.Namespace) -> PubPlan:
    if not (args.rate > 0 and math.isfinite(args.rate)):
        raise CliError(f"--rate must be > 0 messages per second, got {args.rate:g}")
    times = 1 if args.once else args.times
    if times is not None and times < 1:
        raise CliError(f"--times must be >= 1, got {times}")
    if args.max_wait < 0 or args.keep_alive < 0:
        raise CliError("--max-wait and --keep-alive must be >= 0 seconds")
    return PubPlan(args.rate, times, args.max_wait, args.keep_alive)


def _pub(args: argparse.Namespace) -> int:
    from zenoh_robot.qos import QoSError, preset

    key = topic_key(args.topic)
    plan = _pub_plan(args)
    deadline = deadline_of(args)
    cls = lookup_type(args.type)
    msg, auto_header = build_message(cls, parse_values(args.values))
    try:
        qos = preset(args.qos)
    except QoSError as exc:
        raise CliError(str(exc)) from None
    with cli_node("topic", args) as node:
        pub = node.create_publisher(cls, "/" + key, qos)
        if plan.times is not None:
            # Sent before a subscription has matched, the message would reach nobody.
            wait_end = time.monotonic() + plan.max_wait
            spin_until(node, lambda: pub.get_subscription_count() > 0,
                       wait_end if deadline is None else min(wait_end, deadline))
            if pub.get_subscription_count() == 0:
                print(f"no matching subscription on /{key} yet: publishing anyway", file=sys.stderr, flush=True)
        print("publisher: beginning loop", flush=True)
        _publish_loop(node, pub, msg, auto_header, plan, deadline)
        spin_until(node, lambda: False, time.monotonic() + plan.keep_alive)
    return 0


def _flow(msg: Any) -> str:
    """The message on one line: ``{data: hello}``."""
    return yaml.safe_dump(_plain(msg.to_dict(), False), default_flow_style=True, sort_keys=False,
                          width=1 << 16).strip()


def _publish_loop(node: "Node", pub: Any, msg: Any, auto_header: bool, plan: PubPlan,
                  deadline: float | None) -> None:
    from zenoh_robot.msgs import Header

    start = time.monotonic()
    sent = 0
    while plan.times is None or sent < plan.times:
        if auto_header:
            msg.header = Header.now(seq=sent + 1)
        try:
            pub.publish(msg)
        except (TypeError, ValueError) as exc:   # e.g. a fixed array of the wrong length
            raise CliError(one_line(str(exc))) from None
        sent += 1
        print(f"publishing #{sent}: {_flow(msg)}", flush=True)
        if plan.times is not None and sent >= plan.times:
            return
        next_at = start + sent / plan.rate
        if deadline is not None and next_at >= deadline:
            return
        spin_until(node, lambda: False, next_at)


_OPS: dict[str, Callable[[argparse.Namespace], int]] = {
    "list": _list, "info": _info, "echo": _echo, "hz": _hz, "pub": _pub,
}
