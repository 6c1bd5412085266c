"""QoS event callbacks (placeholder until the QoS-events work lands)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional


@dataclass
class SubscriptionEventCallbacks:
    deadline: Optional[Callable[[Any], None]] = None
    liveliness: Optional[Callable[[Any], None]] = None
    incompatible_qos: Optional[Callable[[Any], None]] = None
    message_lost: Optional[Callable[[Any], None]] = None
    matched: Optional[Callable[[Any], None]] = None
