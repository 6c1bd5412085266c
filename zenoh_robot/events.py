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


@dataclass(frozen=True)
class SilentStreamInfo:
    """A matched publisher sent nothing for ``window_s`` (``silent``), or samples came again (zenoh_robot.silence)."""
    silent: bool
    window_s: float
    publishers: int                # matched publishers now
    for_s: float                   # silent for (recovered: how long it was silent)
    total_count: int               # silent episodes so far
    ever_received: bool            # a sample arrived before the silence began
    redeclared: bool = False       # the subscriber was declared again to recover (zenoh_robot.silence)

    def describe(self, topic: str) -> str:
        if not self.silent:
            return f"{topic}: samples again after {self.for_s:.1f} s of silence"
        who = "publisher seen" if self.publishers == 1 else f"{self.publishers} publishers seen"
        again = "; subscription declared again" if self.redeclared else ""
        return f"{topic}: {who}, 0 samples in {self.window_s:g} s{again}"


@dataclass(frozen=True)
class DuplicateNodeInfo:
    """Another session holds this node's fully qualified name too (``zenoh_robot.claim``); ``alive`` False:
    it no longer does. Both sides get the same verdict: the later claim (``since``, then the zid) ``yields``."""
    fqn: str
    other_zid: str
    other_since_ns: int
    yields: bool
    alive: bool = True

    def describe(self) -> str:
        if not self.alive:
            return f"node {self.fqn}: the other session holding this name (zid {self.other_zid}) is gone"
        verdict = "this one started later and must stop" if self.yields else "the other started later and must stop"
        return f"node {self.fqn} is also running in session zid {self.other_zid}: {verdict}"


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
    silent_stream: Callback = None       # SilentStreamInfo; set, it turns the watch on (zenoh_robot.silence)


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
