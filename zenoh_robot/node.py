"""The rclpy-shaped Node: owns one Zenoh session and the entities declared on it."""
from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any, Callable, TypeVar

import zenoh

from . import names
from .executor import Executor, Timer
from .graph import EndpointType, GraphMixin
from .parameters import ParametersMixin
from .services import ServicesMixin
from .message import Message
from .publisher import Publisher
from .qos_monitor import QoSMonitor
from ._wire.repeater import Repeater
from .qos import QoSProfile, SYSTEM_DEFAULT
from .session_config import SessionConfig, open_session
from .subscription import Subscription

M = TypeVar("M", bound=Message)

_zenoh_log_once = threading.Lock()
_zenoh_log_done = False


def _init_zenoh_logging() -> None:
    global _zenoh_log_done
    with _zenoh_log_once:
        if not _zenoh_log_done:
            # Zenoh's own logs are noisy at info; RUST_LOG still overrides.
            zenoh.init_log_from_env_or("error")
            _zenoh_log_done = True


class Node(GraphMixin, ServicesMixin, ParametersMixin):
    """``with Node("gcs", namespace="uav1") as node: ...`` - always closes its session.

    Graph, services and parameters live in their own mixin modules; each has an
    ``_init_*`` hook called at the end of ``__init__``.
    """

    def __init__(self, name: str, namespace: str | None = None,
                 config: SessionConfig | str | Path | None = None, *,
                 executor: Executor | None = None,
                 parameter_overrides: dict[str, Any] | None = None,
                 enable_topic_statistics: Any = False) -> None:
        self.name = names.validate_node_name(name)
        self.namespace = names.normalize_namespace(namespace)
        self.executor = executor or Executor()
        self._logger = logging.getLogger(f"zenoh_robot.{self.fully_qualified_name.strip('/').replace('/', '.')}")
        _init_zenoh_logging()
        self.session = open_session(config)
        self._closed = False
        self._lock = threading.Lock()
        self.publishers: list[Publisher[Any]] = []
        self.subscriptions: list[Subscription[Any]] = []
        self.timers: list[Timer] = []
        self._on_close: list[Callable[[], None]] = []
        self.enable_topic_statistics = enable_topic_statistics
        self._repeater: Repeater | None = None
        self._qos_monitor: QoSMonitor | None = None
        try:
            self._init_graph()
            self._init_services()
            self._init_parameters(parameter_overrides or {})
        except BaseException:
            self.close()
            raise

    # -- identity ------------------------------------------------------------------
    @property
    def fully_qualified_name(self) -> str:
        return f"/{self.namespace}/{self.name}" if self.namespace else f"/{self.name}"

    def get_name(self) -> str:
        return self.name

    def get_namespace(self) -> str:
        return "/" + self.namespace

    def get_logger(self) -> logging.Logger:
        return self._logger

    def resolve_topic_name(self, topic: str) -> str:
        return names.resolve_topic(topic, self.namespace, self.name)

    # -- entities ------------------------------------------------------------------
    def create_publisher(self, msg_type: type[M], topic: str, qos: QoSProfile | int = SYSTEM_DEFAULT,
                         *, event_callbacks: Any = None) -> Publisher[M]:
        self._check_open()
        key = self.resolve_topic_name(topic)
        pub = Publisher(self, msg_type, topic, key, _qos(qos), event_callbacks)
        with self._lock:
            self.publishers.append(pub)
        self._match_existing(pub, EndpointType.SUBSCRIPTION)
        return pub

    def create_subscription(self, msg_type: type[M], topic: str, callback: Callable[..., Any],
                            qos: QoSProfile | int = SYSTEM_DEFAULT, *,
                            event_callbacks: Any = None, topic_statistics: Any = None) -> Subscription[M]:
        """``callback(msg)`` or ``callback(msg, info)`` (info: MessageInfo with age, seq).

        ``topic_statistics``: True or a ``TopicStatisticsOptions`` to publish windowed
        age/period statistics for this subscription; None follows the node's
        ``enable_topic_statistics``.
        """
        self._check_open()
        key = self.resolve_topic_name(topic)
        sub = Subscription(self, msg_type, topic, key, callback, _qos(qos), event_callbacks)
        with self._lock:
            self.subscriptions.append(sub)
        self._match_existing(sub, EndpointType.PUBLISHER)
        stats = self.enable_topic_statistics if topic_statistics is None else topic_statistics
        if stats and msg_type._type_name != "zenoh_robot/TopicStatistics":
            from .topic_statistics import attach   # lazy: most nodes never use it
            try:
                sub.statistics = attach(self, sub, None if stats is True else stats)
            except BaseException:
                self.destroy_subscription(sub)
                raise
        return sub

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Timer:
        self._check_open()
        timer = Timer(period_s, callback, self.executor)
        self.executor.add_timer(timer)
        with self._lock:
            self.timers.append(timer)
        return timer

    def destroy_publisher(self, pub: Publisher[Any]) -> None:
        with self._lock:
            if pub in self.publishers:
                self.publishers.remove(pub)
        pub.destroy()

    def destroy_subscription(self, sub: Subscription[Any]) -> None:
        with self._lock:
            if sub in self.subscriptions:
                self.subscriptions.remove(sub)
        sub.destroy()

    def destroy_timer(self, timer: Timer) -> None:
        timer.cancel()

    @property
    def repeater(self) -> "Repeater":
        """The thread that sends delayed copies for publishers with ``repeat`` (made on first use)."""
        with self._lock:
            if self._repeater is None:
                self._repeater = Repeater()
            return self._repeater

    @property
    def qos_monitor(self) -> QoSMonitor:
        """The thread that checks deadlines and leases (made on first use)."""
        with self._lock:
            if self._qos_monitor is None:
                self._qos_monitor = QoSMonitor()
            return self._qos_monitor

    def qos_monitor_if_any(self, fn: Callable[[QoSMonitor], None]) -> None:
        monitor = self._qos_monitor
        if monitor is not None:
            fn(monitor)

    def add_on_close(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` when the node closes, before its session does (for add-ons)."""
        self._on_close.append(fn)

    # -- spinning ------------------------------------------------------------------
    def spin(self, timeout: float | None = None) -> None:
        """Run callbacks until shutdown() or Ctrl-C (or ``timeout`` seconds)."""
        try:
            self.executor.spin(timeout=timeout)
        except KeyboardInterrupt:
            self.get_logger().info("interrupted")

    def spin_once(self, timeout: float | None = None) -> bool:
        return self.executor.spin_once(timeout)

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``predicate()`` is true; returns whether it became true in time."""
        self.executor.spin(until=predicate, timeout=timeout)
        return predicate()

    def shutdown(self) -> None:
        """Stop spin(); the session stays open until close() (or the with-block ends)."""
        self.executor.shutdown()

    # -- lifetime ------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"node {self.fully_qualified_name} is closed")

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self.executor.shutdown()
        for fn in reversed(self._on_close):
            try:
                fn()
            except Exception:
                self._logger.exception("close hook failed")
        for t in self.timers:
            t.cancel()
        if self._repeater is not None:
            self._repeater.close()
        if self._qos_monitor is not None:
            self._qos_monitor.close()
        for entity in [*self.subscriptions, *self.publishers]:
            entity.destroy()
        self._close_graph()
        self.session.close()

    destroy_node = close

    def __enter__(self) -> "Node":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        # Last resort: an unclosed Zenoh session can hang interpreter exit.
        try:
            if not self._closed:
                self.close()
        except Exception:
            pass


def _qos(qos: QoSProfile | int) -> QoSProfile:
    if isinstance(qos, QoSProfile):
        return qos
    if isinstance(qos, int) and not isinstance(qos, bool):
        return SYSTEM_DEFAULT.replace(depth=qos)   # rclpy accepts a bare depth
    raise TypeError(f"qos must be a QoSProfile or a depth, got {qos!r}")
