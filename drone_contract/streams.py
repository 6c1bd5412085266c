"""The drone's streams and whole configurations for a GCS-drone link: the QoS of each stream, the
image path, the transport.

``STREAM_SPECS`` is the one table of the streams between a GCS and a drone: the topic (under the
drone's namespace), who publishes it and what type it carries. The companion and the GCS declare
their publishers and subscriptions from it, and tests/wing/test_contract.py fails when a stream is
declared here but not wired on both sides.

The thesis compared two launch variants (every stream RELIABLE, or every stream
BEST_EFFORT, raw images); ``resilient`` is ours. A profile is more than QoS: how
images travel and how the Zenoh session is tuned are part of what survives loss,
so they are chosen together and written into every result.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from zenoh_robot.image import ImageMode
from zenoh_robot.message import Message
from zenoh_robot.msgs import SensorCombined
from zenoh_robot.qos import RESILIENT, HistoryPolicy, Priority, QoSError, QoSProfile, ReliabilityPolicy
from zenoh_robot.session_config import LOSSY_LINK, SessionConfig

from .limits import SETPOINT_DEADLINE_S as SETPOINT_DEADLINE
from .messages import DroneSetpoint, FailsafeEvent, GcsPresence, VehicleState

UP = "up"         # GCS -> drone
DOWN = "down"     # drone -> GCS


@dataclass(frozen=True)
class StreamSpec:
    """One stream of the contract: ``<drone id>/<name>``, published by the drone (down) or the GCS (up).
    ``message`` is None where the type follows the profile's image mode (``zenoh_robot.image``)."""
    name: str
    direction: str
    message: type[Message] | None
    description: str


STREAM_SPECS: dict[str, StreamSpec] = {s.name: s for s in (
    StreamSpec("setpoint", UP, DroneSetpoint, "position or velocity targets from the GCS in control"),
    StreamSpec("sensor", DOWN, SensorCombined, "PX4's IMU (HIGHRES_IMU) at the sensor rate"),
    StreamSpec("state", DOWN, VehicleState, "mode, arming, position, battery, the companion's lifecycle"),
    StreamSpec("image", DOWN, None, "the camera, as the profile's image mode carries it"),
    StreamSpec("events", DOWN, FailsafeEvent, "what the companion saw and did: refusals, failsafes, control"),
    StreamSpec("presence", UP, GcsPresence, "the GCS in control is still running (renews its control lease)"),
)}
STREAMS = tuple(STREAM_SPECS)


def wired(name: str, direction: str) -> StreamSpec:
    """The contract's stream ``name`` as one side wires it: ``direction`` is the way that side
    expects it to flow (UP: the GCS publishes, DOWN: the drone does); a mismatch is a wiring bug."""
    spec = STREAM_SPECS[name]
    if spec.direction != direction:
        raise ValueError(f"stream {name} flows {spec.direction} in the contract, wired as {direction}")
    return spec


def message_of(spec: StreamSpec) -> type[Message]:
    """The stream's message type; the image's follows the profile's image mode instead."""
    if spec.message is None:
        raise ValueError(f"stream {spec.name}: its message type follows the profile's image mode")
    return spec.message
IMAGE_MODES = tuple(mode.value for mode in ImageMode)   # the library's modes, as CLI choices
SETPOINT_REPEAT_CEILING = 64
TRANSPORT_KINDS = ("unicast", "multicast", "auto")


@dataclass(frozen=True)
class StreamProfile:
    name: str
    description: str
    qos: dict[str, QoSProfile]
    image_mode: str = "raw"                 # an ImageMode: raw (rgb8 Image), jpeg (one JPEG Image), sliced
                                            # (JPEG strips), fec (one JPEG in shares + parity): zenoh_robot.image
    jpeg_quality: int = 70
    # Each end measures the loss it sees and tells the other (zenoh_robot/loss_feedback.LossMonitor): setpoint
    # copies and image parity follow it instead of being sized for the worst case.
    loss_feedback: bool = False
    # SessionConfig keyword overrides: what the transport needs to live through loss.
    transport: dict[str, Any] = field(default_factory=dict)
    # "unicast": a plain session (TCP/UDP links); "multicast": Zenoh's UDP multicast transport on the
    # interface the caller names (SessionConfig.resilient); "auto": multicast when an interface is given.
    transport_kind: str = "unicast"

    def with_overrides(self, params: dict[str, Any]) -> "StreamProfile":
        """Apply the thesis's node parameters (reliability, history, depth) to every stream."""
        keys = {k: params[k] for k in ("reliability", "history", "depth") if k in params}
        if not keys:
            return self
        try:
            new = {name: q.replace(**keys) for name, q in self.qos.items()}
        except QoSError as exc:
            raise QoSError(f"parameters {sorted(keys)}: {exc}") from None
        return replace(self, qos=new, name=f"{self.name}+params")

    def session_config(self, iface: str | None = None) -> SessionConfig:
        """The Zenoh session this profile's transport asks for; ``iface`` is the network interface
        towards the peers (multicast). A profile that needs multicast without one: a one-line error."""
        if self.transport_kind not in TRANSPORT_KINDS:
            raise QoSError(f"profile {self.name}: transport {self.transport_kind!r} is not one of {TRANSPORT_KINDS}")
        if iface is not None and not iface.strip():
            raise QoSError("--iface: empty interface name")
        if self.transport_kind == "multicast" and iface is None:
            raise QoSError(f"profile {self.name} uses the UDP multicast transport: give --iface IFACE "
                           f"(the network interface towards the peers, e.g. wlan0) or --zenoh FILE")
        if iface is not None and self.transport_kind in ("multicast", "auto"):
            return SessionConfig.resilient(iface, **self.transport)
        if iface is not None:
            raise QoSError(f"profile {self.name} uses a unicast transport: --iface applies to multicast "
                           f"profiles ({', '.join(n for n, p in PROFILES.items() if p.transport_kind != 'unicast')})")
        return SessionConfig(**self.transport)

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description, "image_mode": self.image_mode,
                "jpeg_quality": self.jpeg_quality, "loss_feedback": self.loss_feedback, "transport": self.transport,
                "transport_kind": self.transport_kind,
                "qos": {k: v.to_dict() for k, v in self.qos.items()}}


def _all(q: QoSProfile) -> dict[str, QoSProfile]:
    return {s: q.replace(deadline=SETPOINT_DEADLINE) if s == "setpoint" else q for s in STREAMS}


def _keep_last_10(reliability: ReliabilityPolicy) -> QoSProfile:
    return QoSProfile(reliability, history=HistoryPolicy.KEEP_LAST, depth=10)


PROFILES: dict[str, StreamProfile] = {
    "reliable": StreamProfile(
        "reliable", "the thesis's RELIABLE variant: every stream reliable, keep last 10, raw images",
        _all(_keep_last_10(ReliabilityPolicy.RELIABLE)), image_mode="raw"),
    "best_effort": StreamProfile(
        "best_effort", "the thesis's BEST_EFFORT variant: every stream best effort, keep last 10, raw images",
        _all(_keep_last_10(ReliabilityPolicy.BEST_EFFORT)), image_mode="raw"),
    "resilient": StreamProfile(
        "resilient",
        "setpoints carry their last 8 samples and the newest is re-sent over 400 ms, 16 to 64 times as "
        "the measured loss and its fades require (loss feedback; 64 until the first report); state "
        "and events carry their last samples and go out 4 times 3 ms apart; sensors best "
        "effort with one delayed copy; images as one JPEG per frame in one-datagram shares plus "
        "Reed-Solomon parity sized from the measured loss (whole or absent, latest frame wins); "
        "UDP multicast transport (no handshake to lose), joins every 250 ms, keep-alives every 100 ms; "
        "unicast or routed: short handshake tries retried at once, UDP links first",
        {
            # Deadline-driven copies: the newest setpoint re-sent 64 times over 0.8 x the 500 ms
            # deadline, a newer one replacing them: ~170 packets/s at 10 Hz, so a gap over 500 ms
            # needs ~85 packets lost in a row (0.9 ** 85 = 1e-4 at 90 % loss). Express off: see
            # docs/zenoh-multicast-stall.md.
            "setpoint": RESILIENT.replace(deadline=SETPOINT_DEADLINE, repeat=SETPOINT_REPEAT_CEILING, express=False),
            # One delayed copy: ~99 % of the 200 Hz stream at 10 % loss, no waiting for anything.
            "sensor": QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=5, priority=Priority.DATA_HIGH, repeat=1),
            "state": QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=1, priority=Priority.INTERACTIVE_HIGH,
                                redundancy=2, repeat=3),
            "image": QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=1, priority=Priority.DATA_LOW),
            "events": RESILIENT.replace(depth=10, priority=Priority.INTERACTIVE_HIGH),
            # Twice a second, each sent 4 times: the lease (5 s) outlives ~40 copies lost in a row.
            "presence": QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=1, priority=Priority.INTERACTIVE_HIGH,
                                   repeat=3),
        },
        image_mode="fec", jpeg_quality=60, loss_feedback=True,
        # Unicast or routed: the handshake and links the lossy-link experiment found to form and survive
        # (SessionConfig.lossy: fast open, UDP first); every kind: batches under the MTU, a 10 s lease
        # held by keep-alives every 100 ms.
        transport=LOSSY_LINK, transport_kind="auto",
    ),
}
# The resilient streams on the multicast transport, which they are measured on (docs/lossy-link.md):
# --iface is required, so a forgotten flag cannot silently fall back to a unicast handshake.
PROFILES["resilient_multicast"] = replace(
    PROFILES["resilient"], name="resilient_multicast", transport_kind="multicast",
    description=PROFILES["resilient"].description + " (multicast required: --iface)")


def stream_profile(name: str, params: dict[str, Any] | None = None, *, image_mode: str | None = None,
                   jpeg_quality: int | None = None) -> StreamProfile:
    """A profile by name, with the thesis's node parameters and image choices applied."""
    try:
        profile = PROFILES[name]
    except KeyError:
        raise QoSError(f"unknown stream profile {name!r}; choose one of {', '.join(PROFILES)}") from None
    if image_mode is not None:
        try:
            mode = ImageMode(image_mode)
        except ValueError as exc:   # names the valid modes
            raise QoSError(str(exc)) from None
        profile = replace(profile, image_mode=mode.value)
    if jpeg_quality is not None:
        if not 1 <= jpeg_quality <= 95:
            raise QoSError(f"JPEG quality {jpeg_quality}: must be 1..95")
        profile = replace(profile, jpeg_quality=jpeg_quality)
    return profile.with_overrides(params or {})
