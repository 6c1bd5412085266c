"""The companion's node parameters: every setting it reads, visible and (where safe) settable.

Each CompanionConfig field is declared as a node parameter whose default is the command-line
flag's value; ``-p name:=value`` (or a launch file's ``params:``) wins over the flag, as in
rclpy. ``zenoh-robot param list|get|describe /uav1/companion`` shows them, and the stream QoS
in force as ``qos.<stream>.reliability|history|depth``. The thesis's ``reliability``,
``history`` and ``depth`` (applied to every stream) are declared when given.

Read-only: whatever is built once at start (streams, timers, camera, the deadline) and
whatever widens what a peer may make the vehicle do (the set_param allow-list, forced
disarm, resuming by itself): a live change there would lift a safety rule mid-flight.

Live (``param set``): limits and rates the companion reads on every use. Owner-only ones
(``Spec.owner_only``: the safety limits and the downlink rates every GCS shares) are accepted
only from the GCS in control (the ControlArbiter's holder, by the request's ``client_id``;
with ``--secure`` the ACL first limits the service to certificates of a GCS of this drone).
Every value is validated against a bounded range, and ``control_lease_s`` stays above
``setpoint_deadline`` (a holder must not lose control before its silence is noticed). A
refusal goes back to the sender with the reason, is counted and is reported to it as a
``param_refused`` event; an accepted change is logged and published as a ``param_changed``
event ("name old -> new") naming its sender.
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

from drone_contract.messages import valid_client_id
from drone_contract.streams import IMAGE_MODES, STREAMS
from zenoh_robot.parameters import (
    InvalidParameterValueError,
    Parameter,
    ParameterType,
    SetParametersResult,
    WriteGuard,
    current_caller,
)

if TYPE_CHECKING:
    from .config import CompanionConfig
    from .control import ControlArbiter
    from .events import EventReporter

QOS_PARAMS = ("reliability", "history", "depth")   # the thesis's node parameters, applied to every stream
QOS_POLICIES = ("reliability", "history", "depth")
PX4_PARAM_NAME = re.compile(r"^[A-Za-z0-9_]{1,16}$")   # PX4's param_info: at most 16 characters
PX4_STREAMS = ("lean", "default")   # which telemetry the companion asks PX4 for (telemetry_bridge.py LEAN_STREAMS_HZ)


def _range(lo: float, hi: float, unit: str) -> Callable[[Any], str]:
    def check(v: Any) -> str:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            return f"{v!r} outside {lo:g}..{hi:g} {unit}".rstrip()
        return ""
    return check


def _any(v: Any) -> str:
    return ""


def _allow_list(v: Any) -> str:
    bad = [n for n in v if not PX4_PARAM_NAME.match(n)]
    return f"not PX4 parameter names: {bad}" if bad else ""


def _px4_streams(v: Any) -> str:
    return "" if v in PX4_STREAMS else f"{v!r}: one of {', '.join(PX4_STREAMS)}"


def _camera(v: Any) -> str:
    return "" if v and len(v) <= 256 else f"{v!r}: 'test', 'none', a device or a file"


@dataclass(frozen=True)
class Spec:
    name: str                 # parameter name = CompanionConfig field
    description: str
    check: Callable[[Any], str] = _any    # "" when the value is acceptable, else why not
    live: bool = False        # settable while running (the companion reads it on every use)
    flag: str = ""            # a value fixed before the node exists: only this flag sets it
    # A live change only from the GCS in control. True unless said otherwise: a limit added
    # later is guarded until someone decides it need not be.
    owner_only: bool = True


SPECS: tuple[Spec, ...] = (
    Spec("drone_id", "drone id, the namespace of the topics", flag="--id"),
    Spec("profile", "stream profile (QoS per stream, image path, transport)", flag="--profile"),
    Spec("image_mode", f"how images travel: {', '.join(IMAGE_MODES)}", flag="--image"),
    Spec("jpeg_quality", "JPEG quality of jpeg/sliced images", flag="--jpeg-quality"),
    Spec("setpoint_deadline", "setpoint QoS deadline before the failsafe HOLD, s (the subscription's)",
         _range(0.05, 60.0, "s")),
    Spec("resume_on_setpoints", "after a failsafe HOLD, resume OFFBOARD by itself when setpoints return"),
    Spec("sensor_rate_hz", "HIGHRES_IMU rate asked of PX4 (MAV_CMD_SET_MESSAGE_INTERVAL), Hz",
         _range(1.0, 1000.0, "Hz"), live=True),
    # Read-only: asked once when PX4 comes up (and again by px4_link after a reboot); a live switch
    # back to default would need every stream restored, for a saving nobody needs mid-flight.
    Spec("px4_streams", "PX4 telemetry asked: lean (only what the companion reads, at the rates it needs) "
         "or default (PX4's own streams; always with --mavlink-tunnel)", _px4_streams),
    # Only when this companion warns about a low sensor rate: no GCS but its own sees a difference.
    Spec("sensor_rate_tolerance", "a sensor_rate_low event when PX4 delivers less than this share of the rate",
         _range(0.0, 1.0, ""), live=True, owner_only=False),
    Spec("state_rate_hz", "VehicleState publication rate, Hz", _range(0.1, 100.0, "Hz")),
    Spec("camera", "camera source: test, none, a device or a video file", _camera),
    Spec("camera_rate_hz", "camera frame rate, Hz", _range(0.1, 120.0, "Hz"), live=True),
    Spec("image_width", "image width, px", _range(16, 4096, "px")),
    Spec("image_height", "image height, px", _range(16, 4096, "px")),
    Spec("max_offset_m", "farthest a position setpoint may lie from the vehicle, m (plus 1 s of its speed)",
         _range(0.5, 100.0, "m"), live=True),
    Spec("max_speed", "fastest velocity setpoint accepted, m/s", _range(0.1, 30.0, "m/s"), live=True),
    Spec("control_lease_s", "a GCS in control without liveliness token loses control after this silence, s",
         _range(0.5, 60.0, "s"), live=True),
    # The geofence (px4_link applies it to every target): live, so an operator can fit it to the
    # field, and owner-only like every safety limit.
    Spec("fence_radius_m", "geofence: farthest horizontal distance from home a target may take the vehicle, m "
         "(PX4's GF_MAX_HOR_DIST)", _range(1.0, 10000.0, "m"), live=True),
    Spec("fence_ceiling_m", "geofence ceiling: highest a target may take the vehicle above home, m "
         "(PX4's GF_MAX_VER_DIST)", _range(1.0, 10000.0, "m"), live=True),
    Spec("fence_floor_m", "geofence floor: lowest a target may take the vehicle above home, m (0: never below "
         "home; a vehicle below it may climb or hold)", _range(-1000.0, 1000.0, "m"), live=True),
    Spec("allow_force_disarm", "accept a forced disarm in flight (the vehicle falls)"),
    Spec("param_allow", "PX4 parameters a GCS may set with set_param", _allow_list),
    Spec("report_interval_s", "repeated refusals: one event per sender and reason per interval, s",
         _range(0.1, 60.0, "s"), live=True),
)
_BY_NAME = {s.name: s for s in SPECS}


def owner_only(name: str) -> bool:
    """May only the GCS in control change ``name`` live? (Read-only ones the store refuses anyway.)"""
    spec = _BY_NAME.get(name)
    return spec is not None and spec.live and spec.owner_only


def lease_refusal(config: CompanionConfig) -> str:
    """Why the lease and the deadline in ``config`` do not fit together, or ""."""
    lease, deadline = config.control_lease_s, config.setpoint_deadline
    if lease <= deadline:
        return (f"control_lease_s {lease:g} s must stay above setpoint_deadline {deadline:g} s "
                "(a silent GCS would lose control before the failsafe notices it)")
    return ""


def fence_refusal(config: CompanionConfig) -> str:
    """Why the fence in ``config`` is no fence (floor at or above the ceiling), or ""."""
    if config.fence_floor_m >= config.fence_ceiling_m:
        return (f"fence_floor_m {config.fence_floor_m:g} m must stay below fence_ceiling_m "
                f"{config.fence_ceiling_m:g} m")
    return ""


def qos_param_names() -> list[str]:
    return [f"qos.{s}.{p}" for s in STREAMS for p in QOS_POLICIES]


def known_names() -> set[str]:
    """Every name ``-p`` may set on the companion."""
    return {*_BY_NAME, *qos_param_names(), *QOS_PARAMS}


class DeclaresParameters(Protocol):
    """A Node, or a bare ParameterStore (to check ``-p`` values before anything starts)."""

    def declare_parameter(self, name: str, default: Any = ..., description: str = ..., read_only: bool = ...,
                          *, type_: ParameterType | None = ...) -> Parameter: ...

    def add_on_set_parameters_callback(self, callback: Any) -> None: ...


class GuardsWrites(Protocol):
    """A Node: where the write guard is installed."""

    def set_parameter_write_guard(self, guard: WriteGuard | None) -> None: ...


def config_value(config: CompanionConfig, name: str) -> Any:
    if name == "profile":
        return config.profile.name.split("+", 1)[0]
    if name == "image_mode":
        return config.profile.image_mode
    if name == "jpeg_quality":
        return config.profile.jpeg_quality
    if name == "camera":
        return config.camera or "none"
    if name == "param_allow":
        return list(config.param_allow)
    return getattr(config, name)


def _qos_values(config: CompanionConfig) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for stream, q in config.profile.qos.items():
        out[f"qos.{stream}.reliability"] = q.reliability.name.lower()
        out[f"qos.{stream}.history"] = q.history.name.lower()
        out[f"qos.{stream}.depth"] = q.depth
    return out


Apply = Callable[[dict[str, Any]], None]


class CompanionParameters:
    """Declares the companion's parameters on ``target`` and guards every change.

    ``declare`` returns the config with the values in force (``-p`` overrides applied);
    ``on_change`` (set once the companion is built) receives accepted live changes;
    ``guard_writes`` (once the control arbiter and the event reporter exist) installs the
    owner check on the node. Threads: the guard and the on-set callback run on the executor
    thread serving the request.
    """

    def __init__(self, config: CompanionConfig) -> None:
        self.config = config
        self.on_change: Apply | None = None
        self.refused = 0          # every refusal: values, owner
        self.refused_owner = 0    # ... of which: not from the GCS in control
        self.changed = 0
        self._control: ControlArbiter | None = None
        self._events: EventReporter | None = None
        self._declaring = True
        self._qos = _qos_values(config)

    def declare(self, target: DeclaresParameters) -> CompanionConfig:
        target.add_on_set_parameters_callback(self.validate)
        values: dict[str, Any] = {}
        for spec in SPECS:
            default = config_value(self.config, spec.name)
            type_ = ParameterType.STRING_ARRAY if spec.name == "param_allow" else None
            desc = spec.description + ("" if spec.live else " (read-only)")
            p = target.declare_parameter(spec.name, default, desc, not spec.live, type_=type_)
            values[spec.name] = p.value
        for name, value in self._qos.items():
            target.declare_parameter(name, value, "QoS in force on this stream (read-only)", True)
        for name in QOS_PARAMS:
            if name in self.config.qos_overrides:
                target.declare_parameter(name, self.config.qos_overrides[name],
                                         f"QoS {name} applied to every stream at start (read-only)", True)
        self._declaring = False
        fields = {k: v for k, v in values.items() if k not in ("profile", "image_mode", "jpeg_quality")}
        fields["camera"] = None if fields["camera"] == "none" else fields["camera"]
        fields["param_allow"] = tuple(fields["param_allow"])
        self.config = replace(self.config, **fields)
        why = lease_refusal(self.config) or fence_refusal(self.config)
        if why:   # values come one at a time while declaring: the pair is judged once all are in
            raise InvalidParameterValueError(why)
        return self.config

    def guard_writes(self, node: GuardsWrites, control: ControlArbiter, events: EventReporter) -> None:
        self._control, self._events = control, events
        node.set_parameter_write_guard(self.check_writer)

    def check_writer(self, names: list[str], caller: str) -> str:
        """The write guard: owner-only names only from the GCS in control; "" or why not."""
        guarded = [n for n in names if owner_only(n)]
        if not guarded or self._control is None:
            return ""
        holder = self._control.holder
        valid = valid_client_id(caller)
        if valid and caller == holder:
            return ""
        what = ", ".join(guarded[:8])
        if not valid:
            why = f"{what}: only the GCS in control may change it; client_id {caller[:64]!r} missing or malformed"
        elif not holder:
            why = f"{what}: only the GCS in control may change it; no GCS in control (send take_control first)"
        else:
            why = f"{what}: only the GCS in control ({holder}) may change it"
        self.refused += 1
        self.refused_owner += 1
        if self._events is not None:
            who = caller if valid else ""
            self._events.refused("param_refused", who, why, f"param set from {who or '<no id>'}: {why}")
        return why

    def validate(self, params: list[Parameter]) -> SetParametersResult:
        """On-set callback: all or nothing; applies an accepted live change."""
        changes: dict[str, Any] = {}
        for p in params:
            spec = _BY_NAME.get(p.name)
            if p.name in self._qos and p.value != self._qos[p.name]:
                return self._refuse(f"{p.name} shows the QoS in force ({self._qos[p.name]!r}): change it with "
                                    "--config QOS.yaml or -p reliability/history/depth")
            if spec is None:
                continue   # qos.* and the thesis's names: read-only, the store refuses live changes
            if spec.flag and p.value != config_value(self.config, p.name):
                return self._refuse(f"{p.name} is set by {spec.flag} ({p.value!r} given)")
            why = spec.check(p.value)
            if why:
                return self._refuse(f"{p.name}: {why}")
            if not self._declaring:
                changes[p.name] = p.value
        if changes:
            new = replace(self.config, **changes)
            why = lease_refusal(new) or fence_refusal(new)
            if why:
                return self._refuse(why)
            self.changed += 1
            old, self.config = self.config, new
            if self.on_change is not None:
                self.on_change(changes)
            self._report_changes(old, changes, current_caller())
        return SetParametersResult(True)

    def _report_changes(self, old: CompanionConfig, changes: dict[str, Any], caller: str) -> None:
        if self._events is None:
            return
        for name, value in changes.items():   # every one: only the holder changes owner-only limits
            if getattr(old, name) == value:
                continue   # set to what it was: nothing changed
            self._events.event("param_changed", f"{name} {getattr(old, name)!r} -> {value!r}", "applied",
                               caller if valid_client_id(caller) else "")

    def _refuse(self, why: str) -> SetParametersResult:
        self.refused += 1
        return SetParametersResult(False, why)
