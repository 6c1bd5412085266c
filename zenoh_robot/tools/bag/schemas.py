"""What a zenoh-robot sample looks like in Foxglove: JSON with a JSON schema, plus foxglove.* views.

Every topic becomes a JSON channel whose schema is generated from the message
dataclass fields (so Foxglove's plots and raw views decode it). Some types also get
typed views Foxglove draws natively, matched on the type *name* and fields so this
layer never imports the drone packages:

- ``zenoh_robot/VehicleState`` (or any type with ``position``/``attitude`` triples, NED):
  ``<topic>/fix`` LocationFix (around a home point), ``<topic>/pose`` PoseInFrame and
  ``/tf`` FrameTransform ``map`` -> ``<ns>/base_link``, in ENU as Foxglove expects;
- ``zenoh_robot/Setpoint``, ``zenoh_robot/DroneSetpoint`` (any ``*Setpoint`` with x, y, z) positions:
  ``<topic>/pose`` PoseInFrame;
- ``sensor_msgs/Image``: ``<topic>/image`` RawImage (CompressedImage when it holds a JPEG);
- ``zenoh_robot/ImageSlice`` (the sliced image mode's JPEG strips): frames reassembled by the
  library's receiver (``zenoh_robot.image.sliced``), re-encoded once as ``<topic>/image`` CompressedImage;
- ``zenoh_robot/ImageShare`` (the fec image mode, ``zenoh_robot.image.fec``): each frame's JPEG rebuilt
  from its shares by the library's FecAssembler, as it was sent, as ``<topic>/image`` CompressedImage.

The views are protobuf messages from foxglove-sdk (schema and encoder in one), used
both by the MCAP recorder and by the live WebSocket bridge.
"""
from __future__ import annotations

import base64
import io
import math
from dataclasses import dataclass
from typing import Any

from zenoh_robot.frames import enu_quaternion, ned_to_enu
from zenoh_robot.message import FieldSpec, lookup, type_support

JSON_SCHEMA = "jsonschema"
RAW_PREFIX = "/_zr/raw"                    # raw channels live under this topic prefix
# A PX4 SITL default home (Zurich): where LocationFix puts local NED position (0, 0, 0).
HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0
EARTH_RADIUS = 6_378_137.0

_INT = {"byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"}


# -- JSON schema and JSON values -----------------------------------------------------------
def _scalar_schema(base: str | type) -> dict[str, Any]:
    if not isinstance(base, str):
        return object_schema(base)
    if base == "bool":
        return {"type": "boolean"}
    if base in _INT:
        return {"type": "integer"}
    if base in ("float32", "float64"):
        return {"type": ["number", "null"]}     # NaN travels as null: JSON has no NaN
    return {"type": "string"}


def _field_schema(spec: FieldSpec) -> dict[str, Any]:
    if spec.is_bytes:
        return {"type": "string", "contentEncoding": "base64"}
    item = _scalar_schema(spec.base)
    if spec.array is None:
        return item
    out: dict[str, Any] = {"type": "array", "items": item}
    if spec.array >= 0:
        out["minItems"] = out["maxItems"] = spec.array
    return out


def object_schema(cls: Any) -> dict[str, Any]:
    """The JSON schema of a message class, from its field specs (nested types inline)."""
    return {"type": "object", "title": type_support(cls).name,
            "properties": {s.name: _field_schema(s) for s in cls._fields_spec}}


RAW_FIELDS_SCHEMA: dict[str, Any] = {"type": "object", "properties": {"raw_fields": {"type": "array"}}}


def jsonable(value: Any) -> Any:
    """Strict-JSON values: bytes as base64, NaN/inf as null, tuples as lists."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(value)).decode("ascii")
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    return value


def local_type(type_name: str, type_hash: str) -> Any | None:
    """The registered class for this name and hash, or None (unknown here, or another version)."""
    from zenoh_robot import image, msgs  # noqa: F401  registers the standard types (and image pieces)
    try:
        cls = lookup(type_name)
    except KeyError:
        return None
    return cls if type_support(cls).name == type_name and type_support(cls).hash == type_hash else None


@dataclass(slots=True)
class Decoded:
    """A wire body as a message (``msg`` None when the type is unknown here) and as a JSON dict."""
    msg: Any
    data: dict[str, Any]


def decode_body(cls: Any | None, body: Any, with_data: bool = True) -> Decoded:
    """``with_data`` False: the message only (its JSON form, base64 and all, is not needed)."""
    if cls is None:
        return Decoded(None, {"raw_fields": jsonable(body)} if with_data else {})
    try:
        msg = type_support(cls).decode(body)
    except (TypeError, ValueError, AttributeError):
        return Decoded(None, {"raw_fields": jsonable(body)} if with_data else {})
    return Decoded(msg, jsonable(msg.to_dict()) if with_data else {})


# -- foxglove views -------------------------------------------------------------------------
@dataclass(slots=True)
class View:
    """One foxglove-typed message derived from a sample, for ``topic``."""
    topic: str
    message: Any        # a foxglove.messages.* instance: .encode(), .get_schema()


def _stamp(ns: int) -> Any:
    from foxglove.messages import Timestamp
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _quat(xyzw: tuple[float, float, float, float]) -> Any:
    from foxglove.messages import Quaternion
    x, y, z, w = xyzw
    return Quaternion(x=x, y=y, z=z, w=w)


def _finite(values: Any, n: int) -> list[float] | None:
    if not isinstance(values, list) or len(values) != n:
        return None
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        return None
    return out if all(math.isfinite(v) for v in out) else None


def _namespace(topic: str) -> str:
    return topic.rsplit("/", 1)[0] or ""


def vehicle_views(topic: str, data: dict[str, Any], stamp_ns: int) -> list[View]:
    from foxglove.messages import FrameTransform, LocationFix, Pose, PoseInFrame, Vector3
    pos, att = _finite(data.get("position"), 3), _finite(data.get("attitude"), 3)
    if pos is None:
        return []
    roll, pitch, yaw = att or (0.0, 0.0, 0.0)
    x, y, z = ned_to_enu(*pos)
    q = _quat(enu_quaternion(roll, pitch, yaw))
    ts = _stamp(stamp_ns)
    lat = HOME_LAT + math.degrees(pos[0] / EARTH_RADIUS)
    lon = HOME_LON + math.degrees(pos[1] / (EARTH_RADIUS * math.cos(math.radians(HOME_LAT))))
    child = f"{_namespace(topic).strip('/') or 'vehicle'}/base_link"
    return [
        View(f"{topic}/fix", LocationFix(timestamp=ts, frame_id=child, latitude=lat, longitude=lon,
                                         altitude=HOME_ALT - pos[2])),
        View(f"{topic}/pose", PoseInFrame(timestamp=ts, frame_id="map", pose=Pose(
            position=Vector3(x=x, y=y, z=z), orientation=q))),
        View("/tf", FrameTransform(timestamp=ts, parent_frame_id="map", child_frame_id=child,
                                   translation=Vector3(x=x, y=y, z=z), rotation=q)),
    ]


def setpoint_views(topic: str, data: dict[str, Any], stamp_ns: int) -> list[View]:
    from foxglove.messages import Pose, PoseInFrame, Vector3
    if data.get("is_velocity"):
        return []
    xyz = _finite([data.get("x"), data.get("y"), data.get("z")], 3)
    if xyz is None:
        return []
    x, y, z = ned_to_enu(*xyz)
    raw_yaw = data.get("yaw")
    yaw = float(raw_yaw) if isinstance(raw_yaw, (int, float)) else 0.0
    return [View(f"{topic}/pose", PoseInFrame(timestamp=_stamp(stamp_ns), frame_id="map", pose=Pose(
        position=Vector3(x=x, y=y, z=z), orientation=_quat(enu_quaternion(0.0, 0.0, float(yaw))))))]


def image_views(topic: str, msg: Any, stamp_ns: int) -> list[View]:
    from foxglove.messages import CompressedImage, RawImage
    if msg is None:
        return []
    ts = _stamp(msg.header.stamp or stamp_ns)
    if msg.encoding == "jpeg":
        return [View(f"{topic}/image", CompressedImage(timestamp=ts, frame_id=msg.header.frame_id,
                                                       data=bytes(msg.data), format="jpeg"))]
    return [View(f"{topic}/image", RawImage(timestamp=ts, frame_id=msg.header.frame_id, width=msg.width,
                                            height=msg.height, encoding=msg.encoding, step=msg.step,
                                            data=bytes(msg.data)))]


class SliceFrames:
    """ImageSlice samples -> whole frames as one JPEG each (the library's reassembly, reused)."""

    def __init__(self, quality: int = 80) -> None:
        from zenoh_robot.image.sliced import SliceReceiver
        self.quality = quality
        self.frames: list[tuple[int, bytes]] = []
        self._assembler = SliceReceiver(callback=self._on_frame)   # no node: fed by hand

    def _on_frame(self, img: Any, info: Any) -> None:
        from PIL import Image as PILImage
        buf = io.BytesIO()
        PILImage.fromarray(img.to_array()).save(buf, format="JPEG", quality=self.quality)
        self.frames.append((img.header.stamp, buf.getvalue()))

    def add(self, msg: Any) -> list[tuple[int, bytes]]:
        self._assembler.add(msg)
        out, self.frames = self.frames, []
        return out


class ViewMaker:
    """Per-topic state (image reassembly) and the mapping from a decoded sample to views."""

    MAX_ASSEMBLERS = 64    # bounded: a peer inventing topics cannot grow this without limit

    def __init__(self) -> None:
        self._slices: dict[str, SliceFrames] = {}
        self._shares: dict[str, Any] = {}     # topic -> zenoh_robot.image.fec.FecAssembler

    def views(self, topic: str, type_name: str, decoded: Decoded, stamp_ns: int) -> list[View]:
        data = decoded.data
        try:
            if type_name == "zenoh_robot/VehicleState" or ("position" in data and "attitude" in data):
                return vehicle_views(topic, data, stamp_ns)
            if type_name.endswith("Setpoint") and {"x", "y", "z"} <= data.keys():   # Setpoint, DroneSetpoint
                return setpoint_views(topic, data, stamp_ns)
            if type_name == "sensor_msgs/Image":
                return image_views(topic, decoded.msg, stamp_ns)
            if type_name == "zenoh_robot/ImageSlice" and decoded.msg is not None:
                return self._slice_views(topic, decoded.msg)
            if type_name == "zenoh_robot/ImageShare" and decoded.msg is not None:
                return self._share_views(topic, decoded.msg)
        except Exception:   # a view is a bonus: a strange sample must never stop the recording
            return []
        return []

    def _slice_views(self, topic: str, msg: Any) -> list[View]:
        from foxglove.messages import CompressedImage
        frames = self._slices.get(topic)
        if frames is None:
            if len(self._slices) >= self.MAX_ASSEMBLERS:
                return []
            frames = self._slices[topic] = SliceFrames()
        return [View(f"{topic}/image", CompressedImage(timestamp=_stamp(stamp), frame_id="camera", data=jpeg,
                                                       format="jpeg"))
                for stamp, jpeg in frames.add(msg)]

    def _share_views(self, topic: str, msg: Any) -> list[View]:
        return _share_views_of(self._shares, self.MAX_ASSEMBLERS, topic, msg)


# Types whose JSON copy only duplicates bytes held better elsewhere (the raw channel, the image view)
BULK_TYPES = frozenset({"zenoh_robot/ImageSlice", "zenoh_robot/ImageShare"})


def _share_views_of(assemblers: dict[str, Any], limit: int, topic: str, msg: Any) -> list[View]:
    from foxglove.messages import CompressedImage

    from zenoh_robot.image.fec import FecAssembler
    assembler = assemblers.get(topic)
    if assembler is None:
        if len(assemblers) >= limit:
            return []
        assembler = assemblers[topic] = FecAssembler()
    frame = assembler.add(msg)
    if frame is None:
        return []
    return [View(f"{topic}/image", CompressedImage(timestamp=_stamp(frame.stamp), frame_id="camera",
                                                   data=frame.jpeg, format="jpeg"))]


def raw_topic(topic: str) -> str:
    return RAW_PREFIX + topic


def encode_json(data: dict[str, Any]) -> bytes:
    import json
    return json.dumps(data, separators=(",", ":"), allow_nan=False).encode()

