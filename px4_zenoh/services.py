"""``link.param`` and ``link.telemetry`` of the Zenoh backend.

Parameters: PX4's zenoh module carries none (no parameter topics or services in PX4 main of
2026-03): every read or write is refused, clearly and counted, so a GCS's ``set_param`` gets the
reason back instead of a timeout.

Telemetry: PX4 publishes every uORB update unthrottled, so there is no rate to ask of PX4. A
requested "message interval" becomes the rate at which the backend takes that topic's samples off
Zenoh (decimated in the callback, before any copy or decode): the lean plan's 20 Hz local position
costs 20 decodes a second, not 124. The MAVLink stream names the companion uses map to the uORB
topics that carry the same data; the vehicle's state topics are never decimated.
"""
from __future__ import annotations

from collections.abc import Callable

from px4_link.commands import CommandAck, CommandUnsupported
from px4_link.telemetry_service import TelemetryView
from px4_link.wire import mavlink2, message_id

from . import topics as tp
from .core import ZenohCore

NO_PARAMS = "parameters are not available over PX4's zenoh module"
SET_MESSAGE_INTERVAL = 511

# MAVLink stream -> the uORB topic with its data (the rate meter counts decoded samples under both names).
STREAM_TOPICS: dict[str, tp.Px4Topic] = {
    "HIGHRES_IMU": tp.SENSOR_COMBINED, "ATTITUDE": tp.ATTITUDE, "LOCAL_POSITION_NED": tp.LOCAL_POSITION,
    "GLOBAL_POSITION_INT": tp.GLOBAL_POSITION, "BATTERY_STATUS": tp.BATTERY, "GPS_RAW_INT": tp.GPS,
    "SYS_STATUS": tp.VEHICLE_STATUS, "HEARTBEAT": tp.VEHICLE_STATUS, "EXTENDED_SYS_STATE": tp.LAND_DETECTED,
}
STATE_TOPICS = frozenset({tp.VEHICLE_STATUS.name, tp.COMMAND_ACK.name, tp.FAILSAFE_FLAGS.name,
                          tp.LAND_DETECTED.name})
_BY_TOPIC: dict[str, list[str]] = {}
for _stream, _topic in STREAM_TOPICS.items():
    _BY_TOPIC.setdefault(_topic.name, []).append(_stream)


class ZenohParam:
    def __init__(self, core: ZenohCore) -> None:
        self._core = core

    def get(self, name: str, timeout: float = 1.0, retries: int = 3) -> float | int:
        self._core.count("params_refused")
        raise CommandUnsupported(0, None, f"param get {name}: {NO_PARAMS}")

    def set(self, name: str, value: float | int, timeout: float = 1.0, retries: int = 3) -> float | int:
        self._core.count("params_refused")
        raise CommandUnsupported(0, None, f"param set {name}={value}: {NO_PARAMS}")


class ZenohTelemetry(TelemetryView[ZenohCore]):
    def __init__(self, core: ZenohCore) -> None:
        super().__init__(core)
        for topic in _BY_TOPIC:
            core.add_message_handler(topic, self._recorder(topic))

    def _recorder(self, topic: str) -> Callable[[object], None]:
        names = [topic, *_BY_TOPIC.get(topic, [])]

        def record(_msg: object) -> None:
            for n in names:
                self.rates.record(n.upper())
        return record

    def request_message_interval(self, message: str | int, hz: float) -> CommandAck:
        """Take ``message``'s topic at ``hz`` (<= 0: not at all). Accepted at once; a stream with no
        uORB topic here is refused (CommandUnsupported) unless it is being switched off."""
        name = message if isinstance(message, str) else _stream_name(message)
        topic = STREAM_TOPICS.get(name.upper()) if name else None
        if topic is None:
            if hz > 0:
                raise CommandUnsupported(SET_MESSAGE_INTERVAL, None,
                                         f"stream {message}: no uORB topic for it over PX4's zenoh module")
            return CommandAck(SET_MESSAGE_INTERVAL, 0, 0, 0.0)
        if isinstance(message, str):
            self.intervals.remember(message_id(message), hz)
        if topic.name not in STATE_TOPICS:
            q = self._core.inbox.queues[topic.name]
            q.period = None if hz <= 0 else 1.0 / hz
            q.due = 0.0
        return CommandAck(SET_MESSAGE_INTERVAL, 0, 0, 0.0)


def _stream_name(mid: int) -> str:
    msg = mavlink2.mavlink_map.get(mid)
    return str(msg.msgname) if msg is not None else ""
