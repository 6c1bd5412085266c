"""``zenoh-robot topic list|info|type|find|echo|hz|bw|delay|pub``: ros2 topic's tools over Zenoh.

TOPIC is absolute (``/uav1/setpoint``; a name without the leading ``/`` means the same).
Readers (echo, hz, bw, delay) request a QoS every publisher can serve (best effort, no
deadline, transient local only when every publisher keeps samples), as ``ros2 topic echo``
does, unless ``--qos-*`` flags ask for one. A sliced image stream reads as images.
TYPE is a registered name (``Setpoint``, ``std_msgs/String``) or a ``.msg`` file.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from zenoh_robot.session_args import add_session_arguments

from .common import (
    CallbackOutput,
    add_duration_arg,
    cli_node,
    deadline_of,
    did_you_mean,
    lookup_type,
    one_line,
    quiet_exit,
    spin_until,
    topic_key,
    wire_of,
)
from .fields import Filter, csv_value, flatten, get_path
from .main import CliError
from .qos_args import add_qos_args, qos_from_args
from .reader import RawSample, adapted_qos, open_reader, shown_type  # noqa: F401
from .values import build_message, flow, parse_values, render_data, render_line, render_sample, to_data  # noqa: F401

if TYPE_CHECKING:
    from zenoh_robot.graph import TopicEndpointInfo
    from zenoh_robot.node import Node
    from zenoh_robot.qos import QoSProfile

REPORT_PERIOD = 1.0           # seconds between hz/bw/delay reports
GRAPH_QUIET = 0.5             # seconds without a new graph entry: discovery has settled


# -- registration ---------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("topic", help="list, inspect, echo, measure and publish topics")
    add_session_arguments(p)
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    o = _op_parser(ops, "list", "topics on the network")
    _graph_args(o)
    o.add_argument("-t", "--show-types", action="store_true", help="show each topic's type")
    o.add_argument("--include-hidden-topics", action="store_true",
                   help="also the topics of actions (<action>/_action/feedback, status), as ros2 topic list")
    o = _op_parser(ops, "info", "a topic's type, publishers, subscriptions, QoS and their compatibility")
    o.add_argument("topic", help="absolute topic name, e.g. /uav1/setpoint")
    _graph_args(o)
    o = _op_parser(ops, "type", "a topic's message type")
    o.add_argument("topic")
    _graph_args(o)
    o = _op_parser(ops, "find", "topics of a message type")
    o.add_argument("type", help="message type, e.g. Setpoint or zenoh_robot/Setpoint")
    _graph_args(o)
    o.add_argument("--include-hidden-topics", action="store_true",
                   help="also the topics of actions (<action>/_action/feedback, status), as ros2 topic find")
    o = _op_parser(ops, "echo", "print a topic's messages")
    _reader_args(o)
    o.add_argument("--count", type=int, metavar="N", help="exit after N messages")
    o.add_argument("--once", action="store_true", help="exit after the first message")
    o.add_argument("--no-arr", action="store_true", help="show arrays as their length only")
    o.add_argument("--field", metavar="PATH", help="print only this field, e.g. header.stamp or gyro.0")
    o.add_argument("--csv", action="store_true", help="one CSV line per message (a header line first)")
    o.add_argument("--filter", metavar="EXPR",
                   help="only messages for which EXPR holds, e.g. 'x > 1 and header.seq %% 2 == 0' "
                        "(fields, literals, comparisons, and/or/not, arithmetic; never evaluated as code)")
    o = _op_parser(ops, "hz", "a topic's receive rate (images: frames per second)")
    _reader_args(o)
    o.add_argument("--window", type=int, default=10_000, metavar="N",
                   help="intervals the statistics cover (default 10000)")
    o = _op_parser(ops, "bw", "a topic's bandwidth (bytes on the wire per second)")
    _reader_args(o)
    o.add_argument("--window", type=int, default=100, metavar="N", help="messages the average covers (default 100)")
    o = _op_parser(ops, "delay", "age of a topic's messages: receive time - header stamp")
    _reader_args(o)
    o.add_argument("--window", type=int, default=10_000, metavar="N", help="messages the statistics cover")
    o = _op_parser(ops, "pub", "publish a message")
    o.add_argument("topic", help="absolute topic name, e.g. /uav1/setpoint")
    o.add_argument("type", help="message type, e.g. std_msgs/String, Setpoint, or a .msg file")
    o.add_argument("values", nargs="?", default="{}",
                   help="fields as YAML, e.g. '{data: hello}' ('{header: auto}' stamps the header)")
    o.add_argument("-r", "--rate", type=float, default=1.0, help="messages per second (default 1)")
    o.add_argument("-t", "--times", type=int, metavar="N", help="publish N messages, then exit")
    o.add_argument("-1", "--once", action="store_true", help="publish one message, then exit")
    o.add_argument("--max-wait", type=float, default=1.0, metavar="S",
                   help="with --once/--times: seconds to wait for a matching subscription first (default 1)")
    o.add_argument("--keep-alive", type=float, default=0.2, metavar="S",
                   help="seconds to stay up after the last message so it is delivered (default 0.2)")
    add_duration_arg(o)
    add_qos_args(o, default_profile="system_default")
    p.set_defaults(func=run)


def _op_parser(ops: argparse._SubParsersAction[argparse.ArgumentParser], name: str,
               help: str) -> argparse.ArgumentParser:
    o = ops.add_parser(name, help=help, description=help)
    add_session_arguments(o)
    return o


def _graph_args(o: argparse.ArgumentParser) -> None:
    o.add_argument("-v", "--verbose", dest="detail", action="store_true", help="more detail")
    o.add_argument("-a", "--all", action="store_true", help="include this command's own endpoints")
    o.add_argument("--timeout", type=float, default=3.0,
                   help="at most this many seconds to learn the graph (default 3)")


def _reader_args(o: argparse.ArgumentParser) -> None:
    o.add_argument("topic", help="absolute topic name, e.g. /uav1/setpoint")
    o.add_argument("--type", help="message type, when the topic carries several")
    o.add_argument("--msg", metavar="FILE.msg", help="read the samples with this .msg definition")
    add_duration_arg(o)
    add_qos_args(o)


@quiet_exit
def run(args: argparse.Namespace) -> int:
    return _OPS[args.op](args)


# -- list / info ------------------------------------------------------------------------------
def _endpoints(node: "Node", topic: str, show_all: bool) -> tuple[list["TopicEndpointInfo"], list["TopicEndpointInfo"]]:
    # Only this listing's own node is left out: another CLI process's endpoints (a `topic pub`'s publisher,
    # an `echo`'s subscription) are real ones, listed as ROS 2 lists `ros2 topic pub`'s.
    own = (node.get_namespace(), node.get_name())

    def visible(infos: list["TopicEndpointInfo"]) -> list["TopicEndpointInfo"]:
        return sorted((e for e in infos if show_all or (e.node_namespace, e.node_name) != own),
                      key=lambda e: (e.node_namespace, e.node_name, e.endpoint_gid))
    return visible(node.get_publishers_info_by_topic(topic)), visible(node.get_subscriptions_info_by_topic(topic))


def discover_graph(node: "Node", timeout: float, found: Callable[[], bool] = lambda: True) -> None:
    """Learn the graph: until ``found()`` and no entry has come for GRAPH_QUIET s, at most ``timeout``.

    A fresh session returns from open once it reaches one peer; the others, and their
    entities, arrive over the next moments: a quiet spell is the sign they all have. A session
    that connected during the spell has not sent its tokens yet, so it restarts the spell. A spell
    before any peer was reached says nothing (a loaded machine scouts slowly): with no peer, the
    whole timeout is waited.
    """
    if not timeout > 0:
        raise CliError(f"--timeout must be > 0 seconds, got {timeout:g}")
    end = time.monotonic() + timeout
    node.refresh_graph(min(1.0, timeout))
    peers = set(node.peers())
    while True:
        since = node.graph.changes
        ready = bool(peers) and found()
        left = end - time.monotonic()
        if left <= 0:
            return
        changed = node.graph.wait_for_change(since, min(GRAPH_QUIET if ready else 0.1, left))
        now = set(node.peers())
        if not now <= peers:
            changed = True
        peers = now
        if ready and not changed:
            return


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


def _list(args: argparse.Namespace) -> int:
    with cli_node("topic", args) as node:
        discover_graph(node, args.timeout)
        for name, _types in node.get_topic_names_and_types():
            if "/_action/" in name and not args.include_hidden_topics:
                continue    # an action's parts: `action list` shows the action
            pubs, subs = _endpoints(node, name, args.all)
            if not (pubs or subs):
                continue
            types = sorted({shown_type(e.topic_type) for e in pubs + subs})
            if args.show_types and not args.detail:
                print(f"{name} [{', '.join(types)}]")
                continue
            if not args.detail:
                print(name)
                continue
            print(f"{name} [{', '.join(types)}] {_plural(len(pubs), 'publisher')}, "
                  f"{_plural(len(subs), 'subscription')}")
    return 0


def _found_endpoints(node: Any, name: str, args: argparse.Namespace) -> tuple[list[Any], list[Any]]:
    """The topic's publishers and subscriptions once discovery settles; a one-line error if none."""
    discover_graph(node, args.timeout, lambda: any(_endpoints(node, name, args.all)))
    pubs, subs = _endpoints(node, name, args.all)
    if not (pubs or subs):
        known = [t for t, _ in node.get_topic_names_and_types()]
        raise CliError(f"topic {name} not found: no publisher or subscription on the graph"
                       + did_you_mean(name, known))
    return pubs, subs


def _info(args: argparse.Namespace) -> int:
    name = "/" + topic_key(args.topic)
    with cli_node("topic", args) as node:
        pubs, subs = _found_endpoints(node, name, args)
        pairs = [(p, s, _verdict(p, s)) for p in pubs for s in subs]
        print(f"Type: {', '.join(sorted({shown_type(e.topic_type) for e in pubs + subs}))}")
        print(f"Publisher count: {len(pubs)}")
        print(f"Subscription count: {len(subs)}")
        humble = sum(1 for e in pubs + subs if e.topic_type_hash == "TypeHashNotSupported")
        if humble:   # zenoh_robot.ros2.compat: their keys carry no hash, so they meet nobody on Jazzy+
            print(f"ROS 2 Humble: {_plural(humble, 'endpoint')} without a type hash (TypeHashNotSupported): "
                  "no data is exchanged with them")
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

    if pub.topic_type_hash != sub.topic_type_hash and sub.topic_type_hash != "any":   # raw subscriptions take all
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




def _type(args: argparse.Namespace) -> int:
    name = "/" + topic_key(args.topic)
    with cli_node("topic", args) as node:
        pubs, subs = _found_endpoints(node, name, args)
        for t in sorted({shown_type(e.topic_type) for e in pubs + subs}):
            print(t)
    return 0


def _find(args: argparse.Namespace) -> int:
    wanted = args.type.strip()
    short = wanted.rsplit("/", 1)[-1]
    with cli_node("topic", args) as node:
        discover_graph(node, args.timeout)
        found = False
        all_types: set[str] = set()
        for name, _types in node.get_topic_names_and_types():
            if "/_action/" in name and not args.include_hidden_topics:
                continue    # an action's parts: `action list` shows the action
            pubs, subs = _endpoints(node, name, args.all)
            seen = {e.topic_type for e in pubs + subs}
            all_types |= seen
            if any(t == wanted or t.rsplit("/", 1)[-1] == short or (short == "Image" and "ImageSlice" in t)
                   for t in seen):
                print(name)
                found = True
        if not found:
            print(f"no topic carries {wanted}" + did_you_mean(wanted, sorted(all_types)), file=sys.stderr)
    return 0


# -- readers ----------------------------------------------------------------------------------
def _open(node: "Node", args: argparse.Namespace, key: str, deadline: float | None,
          deliver: Callable[[Any, int, int], None]) -> str:
    return open_reader(node, key, args.type, deadline, deliver, qos=qos_from_args(args), msg_file=args.msg)


def _echo(args: argparse.Namespace) -> int:
    key = topic_key(args.topic)
    deadline = deadline_of(args)
    limit = 1 if args.once else args.count
    if limit is not None and limit < 1:
        raise CliError(f"--count must be >= 1, got {limit}")
    keep = Filter(args.filter) if args.filter else None
    out = CallbackOutput()
    printed = 0
    columns: list[str] | None = None
    bad_field: list[str] = []

    def show(value: Any, _received_ns: int, _size: int) -> None:
        nonlocal printed, columns
        if limit is not None and printed >= limit or bad_field:
            return     # samples already queued when the count is reached
        data = to_data(value)
        if keep is not None and not keep(data):
            return
        if args.field:
            try:
                data = get_path(data, args.field)
            except KeyError as exc:
                bad_field.append(str(exc.args[0]))
                return
        if args.csv:
            flat = flatten(data) if isinstance(data, (dict, list)) else {args.field or "value": data}
            if columns is None:
                columns = list(flat)
                out.print(",".join(csv_value(c) for c in columns))
            out.print(",".join(csv_value(flat.get(c)) for c in columns))
        elif args.field:
            out.print(render_line(data, args.no_arr))
        else:
            out.print(f"{render_data(data, args.no_arr)}\n---")
        printed += 1

    with cli_node("topic", args) as node:
        _open(node, args, key, deadline, show)
        spin_until(node, lambda: out.closed or bool(bad_field) or (limit is not None and printed >= limit), deadline)
    if bad_field:
        raise CliError(f"--field: {bad_field[0]}")
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
        intervals = [(b - a) / 1e9 for a, b in zip(s, s[1:], strict=False)]
        if not intervals:
            return None
        mean = sum(intervals) / len(intervals)
        std = math.sqrt(sum((x - mean) ** 2 for x in intervals) / len(intervals))
        rate = 1.0 / mean if mean > 0 else float("inf")
        return (f"average rate: {rate:.3f}\n\tmin: {min(intervals):.3f}s max: {max(intervals):.3f}s "
                f"std dev: {std:.5f}s window: {len(intervals)}")


class _Reporter:
    """Prints a report each REPORT_PERIOD, or 'no new messages'."""

    def __init__(self, out: CallbackOutput, text: Callable[[], str | None], count: Callable[[], int]) -> None:
        self.out, self.text, self.count, self.reported = out, text, count, 0

    def __call__(self) -> None:
        total = self.count()
        if total == self.reported:
            if self.reported:
                self.out.print("no new messages")
            return
        self.reported = total
        text = self.text()
        if text:
            self.out.print(text)


def _measure(args: argparse.Namespace, add: Callable[[Any, int, int], None], report: _Reporter,
             out: CallbackOutput) -> int:
    key = topic_key(args.topic)
    deadline = deadline_of(args)
    if args.window < 1:
        raise CliError(f"--window must be >= 1, got {args.window}")
    with cli_node("topic", args) as node:
        type_name = _open(node, args, key, deadline, add)
        if type_name.endswith("/ImageSlice"):
            print(f"/{key} is a sliced image stream: counting whole frames", file=sys.stderr, flush=True)
        node.create_timer(REPORT_PERIOD, report)
        spin_until(node, lambda: out.closed, deadline)
    out.check()
    return 0


def _hz(args: argparse.Namespace) -> int:
    window = RateWindow.of(max(args.window, 1))
    out = CallbackOutput()
    return _measure(args, lambda _v, received_ns, _s: window.add(received_ns),
                    _Reporter(out, window.report, lambda: window.total), out)


@dataclass
class BandwidthWindow:
    """Sizes and arrival times of the last messages: ros2 topic bw's figures."""
    sizes: deque[tuple[int, int]]
    total: int = 0

    def add(self, received_ns: int, size: int) -> None:
        self.sizes.append((received_ns, size))
        self.total += 1

    def report(self) -> str | None:
        if len(self.sizes) < 2:
            return None
        span = (self.sizes[-1][0] - self.sizes[0][0]) / 1e9
        sizes = [s for _t, s in self.sizes]
        rate = sum(sizes[1:]) / span if span > 0 else float("inf")
        return (f"{_bytes(rate)}/s from {len(sizes)} messages\n\tMessage size mean: {_bytes(sum(sizes) / len(sizes))} "
                f"min: {_bytes(min(sizes))} max: {_bytes(max(sizes))}")


def _bytes(n: float) -> str:
    for unit in ("B", "KB", "MB"):
        if n < 1000:
            return f"{n:.2f} {unit}"
        n /= 1000
    return f"{n:.2f} GB"


def _bw(args: argparse.Namespace) -> int:
    window = BandwidthWindow(deque(maxlen=max(args.window, 1)))
    out = CallbackOutput()
    return _measure(args, lambda _v, received_ns, size: window.add(received_ns, size),
                    _Reporter(out, window.report, lambda: window.total), out)


def header_stamp_ns(value: Any) -> int | None:
    data = to_data(value)
    stamp = data.get("header", {}).get("stamp") if isinstance(data, dict) and isinstance(data.get("header"), dict) \
        else None
    if isinstance(stamp, dict):    # builtin_interfaces/Time
        stamp = int(stamp.get("sec", 0)) * 1_000_000_000 + int(stamp.get("nanosec", 0))
    return int(stamp) if isinstance(stamp, (int, float)) and not isinstance(stamp, bool) and stamp > 0 else None


def _delay(args: argparse.Namespace) -> int:
    delays: deque[float] = deque(maxlen=max(args.window, 1))
    counts = {"total": 0, "unstamped": 0}
    out = CallbackOutput()

    def add(value: Any, received_ns: int, _size: int) -> None:
        counts["total"] += 1
        stamp = header_stamp_ns(value)
        if stamp is None:
            counts["unstamped"] += 1
            return
        delays.append((received_ns - stamp) / 1e9)

    def report() -> str | None:
        if not delays:
            return "messages have no header stamp: no delay to measure" if counts["unstamped"] else None
        d = list(delays)
        mean = sum(d) / len(d)
        std = math.sqrt(sum((x - mean) ** 2 for x in d) / len(d))
        return (f"average delay: {mean:.3f}\n\tmin: {min(d):.3f}s max: {max(d):.3f}s std dev: {std:.5f}s "
                f"window: {len(d)}")

    return _measure(args, add, _Reporter(out, report, lambda: counts["total"]), out)


# -- pub ----------------------------------------------------------------------------------------
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
    key = topic_key(args.topic)
    plan = _pub_plan(args)
    deadline = deadline_of(args)
    cls = lookup_type(args.type, ros2=wire_of(args).name == "ros2")
    msg, auto_header = build_message(cls, parse_values(args.values))
    qos = qos_from_args(args)
    assert qos is not None   # pub's parser has a default profile (system_default)
    with cli_node("topic", args) as node:
        pub = node.create_publisher(cls, "/" + key, qos)
        if plan.times is not None:
            # Sent before a subscription has matched, the message would reach nobody.
            wait_end = time.monotonic() + plan.max_wait
            spin_until(node, lambda: pub.get_subscription_count() > 0,
                       wait_end if deadline is None else min(wait_end, deadline))
            if pub.get_subscription_count() == 0:
                print(f"no matching subscription on /{key} yet: publishing anyway", file=sys.stderr, flush=True)
        print(f"publisher: beginning loop (QoS {qos!r})", flush=True)
        _publish_loop(node, pub, msg, auto_header, plan, deadline)
        spin_until(node, lambda: False, time.monotonic() + plan.keep_alive)
    return 0


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
        print(f"publishing #{sent}: {flow(msg)}", flush=True)
        if plan.times is not None and sent >= plan.times:
            return
        next_at = start + sent / plan.rate
        if deadline is not None and next_at >= deadline:
            return
        spin_until(node, lambda: False, next_at)


_OPS: dict[str, Callable[[argparse.Namespace], int]] = {
    "list": _list, "info": _info, "type": _type, "find": _find, "echo": _echo, "hz": _hz, "bw": _bw,
    "delay": _delay, "pub": _pub,
}
