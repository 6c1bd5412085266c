"""The ROS graph over Zenoh liveliness tokens (filled in by the graph/QoS-events work)."""
from __future__ import annotations

from typing import Any


class GraphMixin:
    """Node methods about the graph: who publishes and subscribes what, with which QoS."""

    def _init_graph(self) -> None:
        pass

    def count_subscribers(self: Any, topic: str) -> int:
        key = self.resolve_topic_name(topic)
        return sum(1 for s in self.subscriptions if s.key == key)

    def count_publishers(self: Any, topic: str) -> int:
        key = self.resolve_topic_name(topic)
        return sum(1 for p in self.publishers if p.key == key)
