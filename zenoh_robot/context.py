"""What an entity may use of the node that made it: the small interface a Node hands its entities.

Publishers, subscriptions, services, clients and their QoS-event state take an
:class:`EntityContext`, never the Node itself, so none of them reaches into the
node's private state and the node can change inside without breaking them. The
context holds the session, the executor, the logger, the node's names, its wire format
(``zenoh_robot.wire``: how samples become bytes and keys), the graph hook that announces
an endpoint, and the two per-node helper threads (made on first use: most nodes never
need them).
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import zenoh

from .executor import Executor
from .qos import QoSProfile
from .qos_monitor import QoSMonitor
from .repeater import Repeater

if TYPE_CHECKING:
    from .graph import EndpointType, TopicEndpointInfo
    from .wire.format import WireFormat


class Endpoint(Protocol):
    """A publisher or subscription as the graph sees it."""

    @property
    def key(self) -> str: ...

    @property
    def gid(self) -> int: ...

    @property
    def qos(self) -> QoSProfile: ...

    @property
    def type_name(self) -> str: ...

    @property
    def type_hash(self) -> str: ...

    def on_peer(self, appeared: bool, info: TopicEndpointInfo) -> None: ...


class NodeClosedError(RuntimeError):
    """An entity was created or used on a node that has closed."""


class EntityContext:
    """The node's side of its entities (see the module doc). Made by the Node; entities only read it."""

    def __init__(self, session: zenoh.Session, executor: Executor, logger: logging.Logger,
                 namespace: str, node_name: str,
                 declare_endpoint: Callable[[EndpointType, Endpoint], Any], wire: WireFormat) -> None:
        self.session = session
        self.wire = wire
        self.executor = executor
        self.logger = logger
        self.namespace = namespace
        self.node_name = node_name
        self.started = time.monotonic()     # services wait out discovery for a while after this
        self._declare_endpoint = declare_endpoint
        self._lock = threading.Lock()
        self._closed = False
        self._repeater: Repeater | None = None
        self._qos_monitor: QoSMonitor | None = None

    @property
    def fully_qualified_name(self) -> str:
        return f"/{self.namespace}/{self.node_name}" if self.namespace else f"/{self.node_name}"

    # -- lifetime ---------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def check_open(self) -> None:
        if self._closed:
            raise NodeClosedError(f"node {self.fully_qualified_name} is closed")

    def mark_closed(self) -> bool:
        """Close once: True for the caller that closed it, False if it already was."""
        with self._lock:
            if self._closed:
                return False
            self._closed = True
            return True

    # -- graph --------------------------------------------------------------------------------
    def declare_endpoint(self, kind: EndpointType, entity: Endpoint) -> Any:
        """Announce ``entity`` in the graph; returns the token to undeclare when it goes."""
        return self._declare_endpoint(kind, entity)

    # -- helper threads -------------------------------------------------------------------------
    @property
    def repeater(self) -> Repeater:
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

    def repeater_stats(self) -> dict[str, float] | None:
        """The repeater's counters (``Repeater.stats``), or None if no publisher ever repeated."""
        repeater = self._repeater
        return None if repeater is None else repeater.stats()

    def qos_monitor_if_any(self, fn: Callable[[QoSMonitor], None]) -> None:
        monitor = self._qos_monitor
        if monitor is not None:
            fn(monitor)

    def close_helpers(self) -> None:
        with self._lock:
            repeater, monitor = self._repeater, self._qos_monitor
        if repeater is not None:
            repeater.close()
        if monitor is not None:
            monitor.close()
