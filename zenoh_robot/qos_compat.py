"""Request-vs-offered QoS compatibility, by ROS 2's rules (rmw_qos_profile_check_compatible).

A publisher *offers* a profile, a subscription *requests* one; the pair matches only
when what is offered is at least what is requested. An incompatible pair does not
communicate, and both sides are told which policy failed.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

from .qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy


class PolicyKind(enum.Enum):
    """Which policy made a pair incompatible (rclpy's QoSPolicyKind names)."""
    INVALID = 0
    DURABILITY = 1
    DEADLINE = 2
    LIVELINESS = 3
    RELIABILITY = 4
    HISTORY = 5
    LIFESPAN = 6
    DEPTH = 7
    LIVELINESS_LEASE_DURATION = 8


class Compatibility(enum.Enum):
    OK = "ok"
    WARNING = "warning"   # a SYSTEM_DEFAULT value: cannot tell before run time
    ERROR = "error"


@dataclass(frozen=True)
class CompatibilityVerdict:
    compatibility: Compatibility
    policy: PolicyKind = PolicyKind.INVALID
    reason: str = ""

    @property
    def compatible(self) -> bool:
        return self.compatibility is not Compatibility.ERROR

    def __str__(self) -> str:
        if self.compatibility is Compatibility.OK:
            return "compatible"
        return f"{self.compatibility.value}: {self.reason}"


def format_duration(seconds: float | None) -> str:
    """A QoS duration for people: ``0.5 s`` or ``infinite``."""
    return "infinite" if seconds is None else f"{seconds:g} s"


def _longer(offered: float | None, requested: float | None) -> bool:
    """A period offered longer than requested (None: infinite) fails the request."""
    return requested is not None and (offered is None or offered > requested)


def _longer_reason(what: str, offered: float | None, requested: float | None) -> str:
    return (f"publisher offers {what} {format_duration(offered)}, subscription requests "
            f"{format_duration(requested)} (offered must be <= requested)")


def check_compatibility(offered: QoSProfile, requested: QoSProfile) -> CompatibilityVerdict:
    """The first failing policy, in ROS 2's order, or OK (WARNING for undecidable defaults)."""
    if (offered.reliability is ReliabilityPolicy.BEST_EFFORT
            and requested.reliability is ReliabilityPolicy.RELIABLE):
        return CompatibilityVerdict(Compatibility.ERROR, PolicyKind.RELIABILITY,
                                    "publisher offers BEST_EFFORT reliability, subscription requests RELIABLE")
    if (offered.durability is DurabilityPolicy.VOLATILE
            and requested.durability is DurabilityPolicy.TRANSIENT_LOCAL):
        return CompatibilityVerdict(Compatibility.ERROR, PolicyKind.DURABILITY,
                                    "publisher offers VOLATILE durability, subscription requests TRANSIENT_LOCAL")
    if _longer(offered.deadline, requested.deadline):
        return CompatibilityVerdict(Compatibility.ERROR, PolicyKind.DEADLINE,
                                    _longer_reason("deadline", offered.deadline, requested.deadline))
    if (offered.liveliness is LivelinessPolicy.AUTOMATIC
            and requested.liveliness is LivelinessPolicy.MANUAL_BY_TOPIC):
        return CompatibilityVerdict(Compatibility.ERROR, PolicyKind.LIVELINESS,
                                    "publisher offers AUTOMATIC liveliness, subscription requests MANUAL_BY_TOPIC")
    if _longer(offered.liveliness_lease_duration, requested.liveliness_lease_duration):
        return CompatibilityVerdict(Compatibility.ERROR, PolicyKind.LIVELINESS_LEASE_DURATION,
                                    _longer_reason("liveliness lease", offered.liveliness_lease_duration,
                                                   requested.liveliness_lease_duration))
    undecided = [name for name in ("reliability", "durability", "liveliness")
                 if "SYSTEM_DEFAULT" in (getattr(offered, name).name, getattr(requested, name).name)]
    if undecided:
        return CompatibilityVerdict(Compatibility.WARNING, PolicyKind[undecided[0].upper()],
                                    f"{undecided[0]} is SYSTEM_DEFAULT on one side; taken as the default")
    return CompatibilityVerdict(Compatibility.OK)
