"""ROS 2-style topic statistics: windowed message age and period per subscription.

Enable it per subscription (``create_subscription(..., topic_statistics=True)`` or
``=TopicStatisticsOptions(window=0.5)``) or for every subscription of a node
(``Node(..., enable_topic_statistics=True)``). Every ``window`` seconds the collector
publishes a ``msgs.TopicStatistics`` with, in milliseconds:

* ``message_age_ms``: received time minus the message's source time, where the source
  time is ``msg.header.stamp`` when the message type has a ``header`` field (as ROS 2
  does), and the envelope's source stamp (the publisher's clock at ``publish()``) for
  types without one. A stamp of 0 means "not stamped": that sample adds no age, so a
  window of only unstamped samples reports age NaN with ``sample_count`` 0. Ages are
  kept even when negative: a negative age shows a clock offset between the hosts,
  hiding it would make a skewed link look healthy.
* ``message_period_ms``: time between consecutive arrivals at this subscription.
  The first sample ever gives no period; the previous arrival carries over window
  boundaries, so a steady stream has one period per sample in every window.

An empty window reports NaN average/min/max/std and ``sample_count`` 0, never the
previous window's values. ``std_dev`` is the population standard deviation.

``busy_pct`` (issue #18, per-stream CPU): the executor time this subscription took over the
window (decoding, checks, statistics hook, the user callback), in % of one core. The
subscription reads ``time.perf_counter_ns()`` once before and once after each drain batch
(up to ``DRAIN_BATCH`` samples) into ``counters.busy_ns``, only when statistics are on (a
collector makes it drain with ``_drain_timed``), so the default receive path is untouched.
It is wall time on the executor thread: on a loaded host it includes time waiting for the GIL
or for a core, i.e. what the stream cost the executor, not pure CPU. With
``TopicStatisticsOptions(cpu_budget_pct=5.0)`` a window above the budget logs a rate-limited
warning naming the topic and counts ``over_budget_windows`` (on the collector and, cumulative,
in the message, whose ``budget_pct`` carries the budget; NaN: none).

The default statistics topic is ``<namespace>/statistics/<topic>``, ``<topic>`` being
the subscription's key without the node's namespace prefix (``uav1/setpoint`` in
namespace ``uav1`` -> ``uav1/statistics/setpoint``; ``chatter`` with no namespace ->
``statistics/chatter``; ``uav1/sensor`` with no namespace -> ``uav1/statistics/sensor``).
``zenoh_robot.tools.recorder.StatisticsRecorder`` writes them as CSV or JSON.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from .msgs import StatisticsEntry, TopicStatistics
from .node import register_subscription_hook
from .qos import QoSProfile, ReliabilityPolicy
from .ratelimit import RateLimitedLog

if TYPE_CHECKING:
    from .message import Message
    from .node import Node
    from .publisher import Publisher
    from .subscription import MessageInfo, Subscription

log = logging.getLogger("zenoh_robot.topic_statistics")

STATISTICS_QOS = QoSProfile(ReliabilityPolicy.RELIABLE, depth=10)


@dataclass(frozen=True)
class TopicStatisticsOptions:
    """``window``: seconds per statistics message; ``topic``: where to publish (None: the
    default ``<namespace>/statistics/<topic>``; a relative name is resolved in the node's
    namespace, a ``/name`` is absolute); ``publish``: False to only compute (``last``,
    listeners) without a publisher; ``cpu_budget_pct``: % of one core this subscription may take
    on the executor per window before a warning (None: no budget)."""
    window: float = 1.0
    topic: str | None = None
    publish: bool = True
    cpu_budget_pct: float | None = None

    def __post_init__(self) -> None:
        w = self.window
        if isinstance(w, bool) or not isinstance(w, (int, float)):
            raise TypeError(f"TopicStatisticsOptions.window must be a number of seconds, got {w!r}")
        if not (w > 0 and math.isfinite(w)):   # NaN fails `w > 0` too
            raise ValueError(f"TopicStatisticsOptions.window must be a finite number of seconds > 0, got {w!r}")
        object.__setattr__(self, "window", float(w))
        if self.topic is not None and (not isinstance(self.topic, str) or not self.topic):
            raise ValueError(f"TopicStatisticsOptions.topic must be a non-empty topic name or None, "
                             f"got {self.topic!r}")
        if not isinstance(self.publish, bool):
            raise TypeError(f"TopicStatisticsOptions.publish must be True or False, got {self.publish!r}")
        b = self.cpu_budget_pct
        if b is not None:
            if isinstance(b, bool) or not isinstance(b, (int, float)):
                raise TypeError(f"TopicStatisticsOptions.cpu_budget_pct must be a % of one core or None, got {b!r}")
            if not (b > 0 and math.isfinite(b)):
                raise ValueError(f"TopicStatisticsOptions.cpu_budget_pct must be a finite % > 0, got {b!r}")
            object.__setattr__(self, "cpu_budget_pct", float(b))


class _Moments:
    """Running count/mean/min/max/population std (Welford: no catastrophic cancellation
    when ages are large and close together, unlike sum of squares)."""
    __slots__ = ("count", "mean", "m2", "minimum", "maximum")

    def __init__(self) -> None:
        self.count = 0
        self.mean = 0.0
        self.m2 = 0.0
        self.minimum = math.inf
        self.maximum = -math.inf

    def add(self, x: float) -> None:
        self.count += 1
        delta = x - self.mean
        self.mean += delta / self.count
        self.m2 += delta * (x - self.mean)
        if x < self.minimum:
            self.minimum = x
        if x > self.maximum:
            self.maximum = x

    def entry(self) -> StatisticsEntry:
        if self.count == 0:
            return StatisticsEntry()     # NaN everywhere, sample_count 0
        return StatisticsEntry(average=self.mean, minimum=self.minimum, maximum=self.maximum,
                               std_dev=math.sqrt(max(self.m2, 0.0) / self.count), sample_count=self.count)


def _has_header(msg_type: type[Message] | None) -> bool:
    if msg_type is None:   # a raw subscription of any type: no schema, so no header to read
        return False
    return any(s.name == "header" and s.is_message and s.array is None for s in msg_type._fields_spec)


_MAX_STAMP_NS = 1 << 63      # beyond int64 ns (year 2262) a stamp is garbage, not a time


def _header_stamp_ns(msg: Any) -> int:
    """The header's stamp in ns, 0 if absent; also takes a ROS ``Time`` (sec, nanosec)
    so types loaded from .msg files with builtin_interfaces/Time work.

    Whatever a peer put there, this returns an int and never raises: a NaN, an infinity,
    a negative or absurdly large stamp, or a stamp of the wrong type is "no stamp" (0).
    """
    try:
        stamp = getattr(getattr(msg, "header", None), "stamp", 0)
        if type(stamp) is float:
            if not math.isfinite(stamp):
                return 0
            stamp = int(stamp)
        elif type(stamp) is not int:
            sec, nanosec = getattr(stamp, "sec", None), getattr(stamp, "nanosec", 0)
            if type(sec) is not int or type(nanosec) is not int:
                return 0
            stamp = sec * 1_000_000_000 + nanosec
        return stamp if 0 < stamp < _MAX_STAMP_NS else 0
    except Exception:   # a hostile object's attributes: no stamp, never a dead subscription
        return 0


def default_statistics_key(namespace: str, sub_key: str) -> str:
    """``<namespace>/statistics/<topic>`` with ``<topic>`` = ``sub_key`` minus ``namespace/``.

    A node at the root (the GCS) takes the topic's first chunk as the namespace, so its
    statistics of ``uav1/sensor`` sit at ``uav1/statistics/sensor`` beside the companion's of
    ``uav1/setpoint`` (not ``statistics/uav1/sensor``): one drone, one statistics prefix.
    """
    if not namespace and "/" in sub_key:
        namespace = sub_key.split("/", 1)[0]
    topic = sub_key
    if namespace and sub_key.startswith(namespace + "/"):
        topic = sub_key[len(namespace) + 1:]
    return "/".join(p for p in (namespace, "statistics", topic) if p)


class TopicStatisticsCollector:
    """Accumulates one subscription's samples and emits a ``TopicStatistics`` per window.

    The sample hook and the timer both run on the node's executor; the lock is there
    for a MultiThreadedExecutor (hook and timer on different threads) and for readers
    of ``last`` on other threads.
    """

    def __init__(self, node: "Node", sub: "Subscription[Any]", options: TopicStatisticsOptions) -> None:
        self.node = node
        self.subscription = sub
        self.options = options
        self.listeners: list[Callable[[TopicStatistics], None]] = []
        self._lock = threading.Lock()
        self._topic_name = "/" + sub.key
        self._node_name = node.fully_qualified_name
        self._use_header = _has_header(sub.msg_type)
        self._age = _Moments()
        self._period = _Moments()
        self._prev_received_ns: int | None = None
        self._window_start_ns = time.time_ns()
        # busy_pct's window is measured on the same clock as the busy time (wall time can step).
        self._window_start_perf = time.perf_counter_ns()
        self._busy_seen_ns = sub.counters.busy_ns   # the subscription's running total at the last window
        self._budget = math.nan if options.cpu_budget_pct is None else options.cpu_budget_pct
        self._rlog = RateLimitedLog(log, burst=1, interval=30.0)   # one line per topic per 30 s
        self._last: TopicStatistics | None = None
        self._closed = False
        self.windows = 0
        self.over_budget_windows = 0
        if options.topic is None:
            self.topic = default_statistics_key(node.namespace, sub.key)
        else:
            self.topic = node.resolve_topic_name(options.topic)   # InvalidNameError says why
        self.publisher: "Publisher[TopicStatistics] | None" = None
        if options.publish:
            # Absolute, so the node does not prefix its namespace a second time.
            self.publisher = node.create_publisher(TopicStatistics, "/" + self.topic, STATISTICS_QOS)
        try:
            sub.sample_hooks.append(self._on_sample)
            self._timer = node.create_timer(options.window, self._on_window)
        except BaseException:
            self.destroy()
            raise

    # -- executor ------------------------------------------------------------------
    def _on_sample(self, msg: Any, info: "MessageInfo") -> None:
        received = info.received_stamp_ns
        stamp = _header_stamp_ns(msg) if self._use_header else info.source_stamp_ns
        if not 0 < stamp < _MAX_STAMP_NS:
            stamp = 0
        with self._lock:
            if stamp:
                self._age.add((received - stamp) / 1e6)
            if self._prev_received_ns is not None:
                self._period.add((received - self._prev_received_ns) / 1e6)
            self._prev_received_ns = received

    def _on_window(self) -> None:
        stop = time.time_ns()
        stop_perf = time.perf_counter_ns()
        counters = self.subscription.counters
        with self._lock:
            if self._closed:
                return
            age, period = self._age, self._period
            self._age, self._period = _Moments(), _Moments()
            start, self._window_start_ns = self._window_start_ns, stop
            elapsed, self._window_start_perf = stop_perf - self._window_start_perf, stop_perf
            total = counters.busy_ns     # Subscription._drain_timed adds each drain batch's time
            busy, self._busy_seen_ns = total - self._busy_seen_ns, total
            busy_pct = 100.0 * busy / elapsed if elapsed > 0 else math.nan
            over = busy_pct > self._budget     # False for a NaN budget or a NaN busy_pct
            if over:
                self.over_budget_windows += 1
            stats = TopicStatistics(topic=self._topic_name, node=self._node_name, window_start=start,
                                    window_stop=stop, message_age_ms=age.entry(),
                                    message_period_ms=period.entry(), received=counters.received,
                                    lost=counters.lost, dropped=counters.dropped, busy_pct=busy_pct,
                                    budget_pct=self._budget, over_budget_windows=self.over_budget_windows)
            self._last = stats
            self.windows += 1
        if over:
            self._rlog.warning("over_budget", "%s took %.1f %% of a core on the executor over the last %.2f s, "
                               "over its budget of %g %% (%d window(s) over so far)", self._topic_name,
                               busy_pct, elapsed / 1e9, self._budget, self.over_budget_windows)
        pub = self.publisher
        if pub is not None:
            try:
                pub.publish(stats)
            except Exception:
                # Closing races with a last tick; statistics must never take the node down.
                if not (self._closed or self.node.closed):
                    log.exception("publishing topic statistics on %r failed", self.topic)
        for listener in list(self.listeners):
            try:
                listener(stats)
            except Exception:
                log.exception("topic statistics listener %r raised", listener)

    # -- any thread ----------------------------------------------------------------
    @property
    def last(self) -> TopicStatistics | None:
        """The latest window's statistics, None before the first window ends."""
        with self._lock:
            return self._last

    @property
    def closed(self) -> bool:
        return self._closed

    def destroy(self) -> None:
        """Stop collecting and publishing; idempotent, and safe after the node has closed."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        timer = getattr(self, "_timer", None)
        if timer is not None:
            timer.cancel()
        try:
            self.subscription.sample_hooks.remove(self._on_sample)
        except ValueError:
            pass
        if self.publisher is not None:
            try:
                self.node.destroy_publisher(self.publisher)
            except Exception:
                log.debug("statistics publisher on %r already gone", self.topic, exc_info=True)

    def __repr__(self) -> str:
        return f"TopicStatisticsCollector({self._topic_name!r} -> {self.topic!r}, window={self.options.window})"


def attach(node: "Node", sub: "Subscription[Any]",
           options: TopicStatisticsOptions | None) -> TopicStatisticsCollector:
    """Collect statistics for ``sub`` (None: default options). Called by create_subscription."""
    if options is None:
        options = TopicStatisticsOptions()
    elif not isinstance(options, TopicStatisticsOptions):
        raise TypeError(f"topic statistics for {sub.topic!r}: expected True or a TopicStatisticsOptions, "
                        f"got {options!r}")
    return TopicStatisticsCollector(node, sub, options)


def with_cpu_budget(setting: Any, cpu_budget_pct: float) -> TopicStatisticsOptions | None:
    """A node's statistics setting (its ``enable_topic_statistics``: False, True or options) with a
    CPU budget, for ``create_subscription(topic_statistics=...)``; None when statistics are off
    (the subscription then follows the node: none)."""
    if not setting:
        return None
    base = setting if isinstance(setting, TopicStatisticsOptions) else TopicStatisticsOptions()
    return replace(base, cpu_budget_pct=cpu_budget_pct)


def _on_new_subscription(node: "Node", sub: "Subscription[Any]", setting: Any) -> None:
    sub.statistics = attach(node, sub, None if setting is True else setting)


register_subscription_hook(_on_new_subscription)

__all__ = ["TopicStatisticsOptions", "TopicStatisticsCollector", "attach", "default_statistics_key",
           "with_cpu_budget"]
