"""QoS profiles in ROS 2's shape, their presets, and YAML load/save.

This module is pure data: how a profile becomes Zenoh options lives in
``qos_mapping``. Durations are seconds (float); ``None`` means infinite.
"""
from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml


class _Policy(enum.Enum):
    def __repr__(self) -> str:  # rclpy prints ReliabilityPolicy.BEST_EFFORT
        return f"{type(self).__name__}.{self.name}"

    @classmethod
    def parse(cls, value: Any) -> "_Policy":
        if isinstance(value, cls):
            return value
        text = str(value).strip().upper().replace("-", "_")
        for prefix in (cls.__name__.upper() + ".", ):
            if text.startswith(prefix):
                text = text[len(prefix):]
        try:
            return cls[text]
        except KeyError:
            raise ValueError(f"{value!r} is not a {cls.__name__}; choose one of "
                             f"{', '.join(m.name.lower() for m in cls)}") from None


class ReliabilityPolicy(_Policy):
    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2


class DurabilityPolicy(_Policy):
    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class HistoryPolicy(_Policy):
    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2


class LivelinessPolicy(_Policy):
    SYSTEM_DEFAULT = 0
    AUTOMATIC = 1
    MANUAL_BY_TOPIC = 3


class Priority(_Policy):
    """Zenoh priorities, highest first (values are Zenoh's)."""
    REAL_TIME = 1
    INTERACTIVE_HIGH = 2
    INTERACTIVE_LOW = 3
    DATA_HIGH = 4
    DATA = 5
    DATA_LOW = 6
    BACKGROUND = 7


# rclpy-style short aliases, as the public API in docs/architecture.md uses them.
Reliability = ReliabilityPolicy
Durability = DurabilityPolicy
History = HistoryPolicy
Liveliness = LivelinessPolicy

KEEP_ALL_LIMIT = 10_000  # KEEP_ALL is bounded too: ROS 2 bounds it by resource limits.


class QoSError(ValueError):
    """A QoS profile or file with a bad key or value; the message names it."""


def _duration(name: str, value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, str) and value.strip().lower() in ("infinite", "inf", "none", ""):
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise QoSError(f"{name}: {value!r} is not a duration in seconds") from None
    if math.isnan(v) or v < 0:
        raise QoSError(f"{name}: {value!r} must be a non-negative number of seconds")
    return None if math.isinf(v) or v == 0 else v


@dataclass(frozen=True)
class QoSProfile:
    reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE
    durability: DurabilityPolicy = DurabilityPolicy.VOLATILE
    history: HistoryPolicy = HistoryPolicy.KEEP_LAST
    depth: int = 10
    deadline: float | None = None
    lifespan: float | None = None
    liveliness: LivelinessPolicy = LivelinessPolicy.AUTOMATIC
    liveliness_lease_duration: float | None = None
    priority: Priority = Priority.DATA
    express: bool = False
    # Beyond ROS 2, for lossy links: each sample carries the last `redundancy` samples of its
    # publisher, and goes out `1 + repeat` times. Small messages only: the cost is bytes.
    redundancy: int = 0
    repeat: int = 0

    def __post_init__(self) -> None:
        enums = {"reliability": ReliabilityPolicy, "durability": DurabilityPolicy,
                 "history": HistoryPolicy, "liveliness": LivelinessPolicy, "priority": Priority}
        for name, cls in enums.items():
            try:
                object.__setattr__(self, name, cls.parse(getattr(self, name)))
            except ValueError as exc:
                raise QoSError(f"{name}: {exc}") from None
        for name in ("deadline", "lifespan", "liveliness_lease_duration"):
            object.__setattr__(self, name, _duration(name, getattr(self, name)))
        depth = self.depth
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
            raise QoSError(f"depth: {depth!r} must be a non-negative integer")
        if self.history is HistoryPolicy.KEEP_LAST and depth == 0:
            raise QoSError("depth: KEEP_LAST needs depth >= 1")
        for name in ("redundancy", "repeat"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 64:
                raise QoSError(f"{name}: {v!r} must be an integer 0..64")
        if not isinstance(self.express, bool):
            raise QoSError(f"express: {self.express!r} must be true or false")

    @property
    def queue_limit(self) -> int:
        """How many unprocessed samples a subscription may hold."""
        if self.history is HistoryPolicy.KEEP_ALL:
            return KEEP_ALL_LIMIT
        return self.depth

    def __repr__(self) -> str:
        parts = [f"reliability={self.reliability!r}", f"durability={self.durability!r}",
                 f"history={self.history!r}", f"depth={self.depth}"]
        default = QoSProfile()
        for f in ("deadline", "lifespan", "liveliness", "liveliness_lease_duration", "priority", "express",
                  "redundancy", "repeat"):
            v = getattr(self, f)
            if v != getattr(default, f):
                parts.append(f"{f}={v!r}")
        return f"QoSProfile({', '.join(parts)})"

    def replace(self, **changes: Any) -> "QoSProfile":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.name.lower() if isinstance(v, enum.Enum) else v
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any], base: "QoSProfile | None" = None) -> "QoSProfile":
        """Build from a mapping; keys absent take ``base``'s values (default: SYSTEM_DEFAULT)."""
        if not isinstance(data, dict):
            raise QoSError(f"a QoS profile must be a mapping, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise QoSError(f"unknown QoS key(s) {unknown}; valid keys: {sorted(known)}")
        return dataclasses.replace(base or SYSTEM_DEFAULT, **data)


SYSTEM_DEFAULT = QoSProfile()
SENSOR_DATA = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=5)
SERVICES_DEFAULT = QoSProfile(ReliabilityPolicy.RELIABLE, depth=10, priority=Priority.INTERACTIVE_HIGH)
PARAMETERS = QoSProfile(ReliabilityPolicy.RELIABLE, depth=1000)
# Robot profiles.
CONTROL = QoSProfile(ReliabilityPolicy.RELIABLE, depth=3, priority=Priority.INTERACTIVE_HIGH, express=True)
CONFIGURATION = QoSProfile(ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL, HistoryPolicy.KEEP_ALL,
                           depth=0)
FEEDBACK = QoSProfile(ReliabilityPolicy.RELIABLE, depth=10)
# A setpoint is only worth its newest value: never queue, never wait, go first.
SETPOINT = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=1, priority=Priority.REAL_TIME, express=True)
SENSOR = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=5, priority=Priority.DATA_HIGH)
IMAGE = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=1, priority=Priority.DATA_LOW)
# Fresh like best effort, complete like reliable: no retransmission queue to age behind,
# yet a lost sample rides along in the next 8 packets, and each packet goes out 4 times.
RESILIENT = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=1, priority=Priority.REAL_TIME, express=True,
                       redundancy=8, repeat=3)

PRESETS: dict[str, QoSProfile] = {
    "system_default": SYSTEM_DEFAULT, "sensor_data": SENSOR_DATA, "services_default": SERVICES_DEFAULT,
    "parameters": PARAMETERS, "control": CONTROL, "configuration": CONFIGURATION, "feedback": FEEDBACK,
    "setpoint": SETPOINT, "sensor": SENSOR, "image": IMAGE, "resilient": RESILIENT,
}


def preset(name: str) -> QoSProfile:
    try:
        return PRESETS[name.strip().lower()]
    except KeyError:
        raise QoSError(f"unknown QoS preset {name!r}; presets: {', '.join(sorted(PRESETS))}") from None


def load_qos(path: str | Path) -> dict[str, QoSProfile]:
    """Load named profiles from YAML: ``{name: {preset: sensor_data, depth: 3, ...}}``.

    A file holding a single profile (keys are QoS keys) loads as ``{"default": profile}``.
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise QoSError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise QoSError(f"{path}: expected a mapping of profile names to QoS settings")
    qos_keys = {f.name for f in dataclasses.fields(QoSProfile)} | {"preset"}
    if set(data) <= qos_keys:
        data = {"default": data}
    out = {}
    for name, body in data.items():
        try:
            out[str(name)] = profile_from_mapping(body)
        except QoSError as exc:
            raise QoSError(f"{path}: profile {name!r}: {exc}") from None
    return out


def profile_from_mapping(body: Any) -> QoSProfile:
    if isinstance(body, str):
        return preset(body)
    if not isinstance(body, dict):
        raise QoSError(f"expected a mapping or a preset name, got {body!r}")
    body = dict(body)
    base = preset(body.pop("preset")) if "preset" in body else None
    return QoSProfile.from_dict(body, base)


def save_qos(profiles: dict[str, QoSProfile] | QoSProfile, path: str | Path) -> None:
    if isinstance(profiles, QoSProfile):
        profiles = {"default": profiles}
    Path(path).write_text(yaml.safe_dump({k: v.to_dict() for k, v in profiles.items()}, sort_keys=False))
