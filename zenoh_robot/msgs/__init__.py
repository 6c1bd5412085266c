"""Standard message types: robot streams (Setpoint, SensorCombined, Image) and common ones."""
from __future__ import annotations

import time

import numpy as np

from ..jpeg import decode_jpeg
from ..message import Message, array, message, ros_field

__all__ = [
    "Header", "Setpoint", "SensorCombined", "Image", "String", "Float32", "Vector3",
    "Quaternion", "Twist", "JointState", "TopicStatistics", "StatisticsEntry",
]


@message(name="std_msgs/Header")
class Header(Message):
    stamp: int = 0        # source time, ns since the Unix epoch
    frame_id: str = ""
    seq: int = 0

    @classmethod
    def now(cls, frame_id: str = "", seq: int = 0) -> "Header":
        return cls(time.time_ns(), frame_id, seq)


@message(name="zenoh_robot/Setpoint")
class Setpoint(Message):
    """A position (m, local NED-free ENU-agnostic frame of the receiver) or velocity (m/s) target."""
    header: Header = None  # type: ignore[assignment]
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0
    is_velocity: bool = False

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@message(name="px4_msgs/SensorCombined")
class SensorCombined(Message):
    """PX4's SensorCombined uORB message, field for field."""
    header: Header = None  # type: ignore[assignment]
    timestamp: int = 0                       # us, PX4 boot time
    gyro_rad: list[float] = array("float32", 3, default=None)
    gyro_integral_dt: int = ros_field("uint32", default=0)
    accelerometer_timestamp_relative: int = ros_field("int32", default=0)
    accelerometer_m_s2: list[float] = array("float32", 3, default=None)
    accelerometer_integral_dt: int = ros_field("uint32", default=0)
    magnetometer_ga: list[float] = array("float32", 3, default=None)
    baro_alt_meter: float = ros_field("float32", default=0.0)
    baro_temp_celcius: float = ros_field("float32", default=0.0)

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()


@message(name="sensor_msgs/Image")
class Image(Message):
    """An image; ``data`` is bytes (raw rows of ``step`` bytes, or one JPEG stream)."""
    header: Header = None  # type: ignore[assignment]
    height: int = ros_field("uint32", default=0)
    width: int = ros_field("uint32", default=0)
    encoding: str = "rgb8"
    is_bigendian: int = ros_field("uint8", default=0)
    step: int = ros_field("uint32", default=0)
    data: bytes = b""

    _CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4}

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()

    @classmethod
    def from_array(cls, arr: np.ndarray, encoding: str | None = None, header: Header | None = None) -> "Image":
        """Wrap an HxW (mono8) or HxWx3 (rgb8) uint8 array; one copy into bytes."""
        if arr.dtype != np.uint8:
            raise ValueError(f"Image.from_array needs uint8, got {arr.dtype}")
        if arr.ndim == 2:
            encoding = encoding or "mono8"
        elif arr.ndim == 3:
            encoding = encoding or {3: "rgb8", 4: "rgba8"}.get(arr.shape[2], "")
            if not encoding:
                raise ValueError(f"Image.from_array: unsupported channel count {arr.shape[2]}")
        else:
            raise ValueError(f"Image.from_array: expected 2 or 3 dimensions, got shape {arr.shape}")
        h, w = arr.shape[:2]
        channels = cls._CHANNELS[encoding]
        return cls(header or Header(), h, w, encoding, 0, w * channels, np.ascontiguousarray(arr).tobytes())

    def to_array(self) -> np.ndarray:
        """A read-only numpy view over ``data`` (no copy); decodes JPEG when encoding is jpeg."""
        if self.encoding == "jpeg":
            return decode_jpeg(self.data)
        channels = self._CHANNELS.get(self.encoding)
        if channels is None:
            raise ValueError(f"Image.to_array: unsupported encoding {self.encoding!r}")
        expected = self.height * self.step
        if len(self.data) != expected:
            raise ValueError(f"Image.to_array: {len(self.data)} bytes, expected {expected} "
                             f"({self.height} rows x {self.step})")
        flat = np.frombuffer(self.data, dtype=np.uint8).reshape(self.height, self.step)
        arr = flat[:, : self.width * channels].reshape(self.height, self.width, channels)
        return arr[:, :, 0] if channels == 1 else arr


@message(name="std_msgs/String")
class String(Message):
    data: str = ""


@message(name="std_msgs/Float32")
class Float32(Message):
    data: float = ros_field("float32", default=0.0)


@message(name="geometry_msgs/Vector3")
class Vector3(Message):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@message(name="geometry_msgs/Quaternion")
class Quaternion(Message):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@message(name="geometry_msgs/Twist")
class Twist(Message):
    linear: Vector3 = None  # type: ignore[assignment]
    angular: Vector3 = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.linear is None:
            self.linear = Vector3()
        if self.angular is None:
            self.angular = Vector3()


@message(name="sensor_msgs/JointState")
class JointState(Message):
    header: Header = None  # type: ignore[assignment]
    name: list[str] = None  # type: ignore[assignment]
    position: list[float] = None  # type: ignore[assignment]
    velocity: list[float] = None  # type: ignore[assignment]
    effort: list[float] = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.header is None:
            self.header = Header()
        for f in ("name", "position", "velocity", "effort"):
            if getattr(self, f) is None:
                setattr(self, f, [])


@message(name="zenoh_robot/StatisticsEntry")
class StatisticsEntry(Message):
    """One metric over a window, as ROS 2 topic statistics: NaN where there is no sample."""
    average: float = float("nan")
    minimum: float = float("nan")
    maximum: float = float("nan")
    std_dev: float = float("nan")
    sample_count: int = 0


@message(name="zenoh_robot/TopicStatistics")
class TopicStatistics(Message):
    __zr_no_statistics__ = True   # statistics of statistics would publish forever
    topic: str = ""
    node: str = ""
    window_start: int = 0     # ns since epoch
    window_stop: int = 0
    message_age_ms: StatisticsEntry = None  # type: ignore[assignment]
    message_period_ms: StatisticsEntry = None  # type: ignore[assignment]
    received: int = 0         # cumulative counters of the subscription
    lost: int = 0
    dropped: int = 0
    # Executor time spent draining this subscription (decode, checks, hooks, callback) over the
    # window, in % of one core (wall time around each drain batch); NaN where not measured.
    busy_pct: float = float("nan")
    budget_pct: float = float("nan")   # TopicStatisticsOptions.cpu_budget_pct; NaN: no budget
    over_budget_windows: int = 0       # cumulative: windows whose busy_pct exceeded budget_pct

    def __post_init__(self) -> None:
        if self.message_age_ms is None:
            self.message_age_ms = StatisticsEntry()
        if self.message_period_ms is None:
            self.message_period_ms = StatisticsEntry()

