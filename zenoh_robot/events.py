"""QoS events in rclpy's shape: status objects and the callbacks that receive them.

Pass ``event_callbacks=PublisherEventCallbacks(...)`` / ``SubscriptionEventCallbacks(...)``
to ``create_publisher`` / ``create_subscription``; each callback gets its status
object on the node's executor (so it runs while the node spins, never on Zenoh's
threads). An incompatible-QoS or incompatible-type event without a callback is
logged as a warning, as rclpy does: a subscription that receives nothing says why.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .qos_compat import PolicyKind


@dataclass(frozen=True)
class _Counted:
    total_count: int
    total_count_change: int


@dataclass(frozen=True)
class QoSRequestedDeadlineMissedInfo(_Counted):
    """A subscription got no sample within its deadline (once per whole period)."""


@dataclass(frozen=True)
class QoSOfferedDeadlineMissedInfo(_Counted):
    """A publisher did not publish within its deadline (once per whole period)."""


@dataclass(frozen=True)
class QoSLivelinessLostInfo(_Counted):
    """A MANUAL_BY_TOPIC publisher did not assert within its lease."""


@dataclass(frozen=True)
class QoSMessageLostInfo(_Counted):
    """Gaps in a publisher's sequence numbers: samples that never reached this process."""


@dataclass(frozen=True)
class QoSLivelinessChangedInfo:
    alive_count: int
    not_alive_count: int
    alive_count_change: int
    not_alive_count_change: int


@dataclass(frozen=True)
class _Incompatible(_Counted):
    last_policy_kind: PolicyKind
    reason: str = ""


@dataclass(frozen=True)
class QoSRequestedIncompatibleQoSInfo(_Incompatible):
    """A publisher offers less than this subscription requests; nothing flows between them."""


@dataclass(frozen=True)
class QoSOfferedIncompatibleQoSInfo(_Incompatible):
    """A subscription requests more than this publisher offers; nothing flows between them."""


@dataclass(frozen=True)
class IncompatibleTypeInfo(_Counted):
    other_type: str = ""


@dataclass(frozen=True)
class MatchedInfo(_Counted):
    current_count: int
    current_count_change: int


Callback = Callable[[Any], None] | None


@dataclass
class PublisherEventCallbacks:
    deadline: Callback = None            # QoSOfferedDeadlineMissedInfo
    liveliness: Callback = None          # QoSLivelinessLostInfo
    incompatible_qos: Callback = None    # QoSOfferedIncompatibleQoSInfo
    incompatible_type: Callback = None   # IncompatibleTypeInfo
    matched: Callback = None             # MatchedInfo


@dataclass
class SubscriptionEventCallbacks:
    deadline: Callback = None            # QoSRequestedDeadlineMissedInfo
    liveliness: Callback = None          # QoSLivelinessChangedInfo
    incompatible_qos: Callback = None    # QoSRequestedIncompatibleQoSInfo
    message_lost: Callback = None        # QoSMessageLostInfo
    incompatible_type: Callback = None   # IncompatibleTypeInfo
    matched: Callback = None             # MatchedInfo


def check_callbacks(callbacks: Any, cls: type) -> Any:
    """A clear TypeError for the wrong kind of callbacks object (or a non-callable field)."""
    if callbacks is None:
        return cls()
    if not isinstance(callbacks, cls):
        raise TypeError(f"event_callbacks must be a {cls.__name__}, got {type(callbacks).__name__}")
    for name, value in vars(callbacks).items():
        if value is not None and not callable(value):
            raise TypeError(f"event_callbacks.{name} is not callable: {value!r}")
    return callbacks
