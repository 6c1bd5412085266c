"""px4_link units without sockets: mode encoding, setpoint checks, command ACK handling."""
from __future__ import annotations

import math
import threading

import px4_helpers  # noqa: F401  (puts the checkout's px4_link first on sys.path)
import pytest

from px4_link import commands as cmds
from px4_link.modes import (
    UnknownModeError,
    decode_custom_mode,
    encode_custom_mode,
    mode_to_main_sub,
    normalize_mode_name,
)
from px4_link.targets import (
    Geofence,
    PositionTarget,
    TargetRefused,
    TargetValidator,
    VehicleMotion,
    VelocityTarget,
    mavlink_fields,
)
from px4_link.telemetry import Imu
from px4_link.wire import Encoder, Parser, float_bits_to_int, int_to_float_bits

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


@pytest.mark.parametrize("name,main,sub", [
    ("MANUAL", 1, 0), ("ALTCTL", 2, 0), ("POSCTL", 3, 0), ("AUTO.TAKEOFF", 4, 2),
    ("AUTO.LOITER", 4, 3), ("AUTO.MISSION", 4, 4), ("AUTO.RTL", 4, 5), ("AUTO.LAND", 4, 6),
    ("ACRO", 5, 0), ("OFFBOARD", 6, 0), ("STABILIZED", 7, 0),
])
def test_mode_encoding_matches_px4(name: str, main: int, sub: int) -> None:
    assert mode_to_main_sub(name) == (main, sub)
    assert encode_custom_mode(name) == (main << 16) | (sub << 24)
    assert decode_custom_mode((main << 16) | (sub << 24)) == name


def test_offboard_custom_mode_is_6_shl_16() -> None:
    assert encode_custom_mode("OFFBOARD") == 6 << 16 == 393216
    assert decode_custom_mode(393216) == "OFFBOARD"


def test_mode_aliases_and_unknowns() -> None:
    assert normalize_mode_name("hold") == "AUTO.LOITER"
    assert normalize_mode_name("Land") == "AUTO.LAND"
    assert normalize_mode_name("RTL") == "AUTO.RTL"
    assert normalize_mode_name("takeoff") == "AUTO.TAKEOFF"
    with pytest.raises(UnknownModeError):
        normalize_mode_name("WARP_DRIVE")
    assert decode_custom_mode((4 << 16) | (99 << 24)).startswith("UNKNOWN")


def test_setpoint_type_masks() -> None:
    assert PositionTarget(1, 2, -3, yaw=0.5).type_mask == 0x9F8
    assert VelocityTarget(1, 0, 0, yaw=0.0).type_mask == 0x9C7
    assert PositionTarget(1, 2, -3).type_mask & 0x400  # no yaw -> yaw ignored
    f = mavlink_fields(PositionTarget(1, 2, -3, yaw=0.5))
    assert (f["coordinate_frame"], f["x"], f["y"], f["z"], f["yaw"]) == (1, 1, 2, -3, 0.5)


@pytest.mark.parametrize("sp,reason", [
    (PositionTarget(math.nan, 0, -2), "non_finite"),
    (PositionTarget(0, math.inf, -2), "non_finite"),
    (VelocityTarget(0, 0, math.nan), "non_finite"),
    (PositionTarget(0, 0, -2, yaw=math.nan), "non_finite"),
    (PositionTarget(200, 0, -2), "geofence"),
    (PositionTarget(0, 0, -80), "geofence"),
    (VelocityTarget(20, 0, 0), "too_fast"),
])
def test_validator_rejects(sp, reason: str) -> None:
    v = TargetValidator(Geofence(max_distance_m=100, max_altitude_m=50), max_speed=10)
    with pytest.raises(TargetRefused) as e:
        v.check(sp, now=0.0)
    assert e.value.reason == reason
    assert isinstance(e.value, ValueError) and str(e.value)


def test_validator_box_and_jump_rules() -> None:
    v = TargetValidator(Geofence(x_range=(-5, 5), y_range=(-5, 5)), max_speed=10)
    with pytest.raises(TargetRefused):
        v.check(PositionTarget(6, 0, -2), now=0.0)
    v.check(PositionTarget(0, 0, -2), now=0.0, vehicle_position=(0, 0, 0))
    v.accept(PositionTarget(0, 0, -2), now=0.0)
    # 0.1 s later: 1 m is fine at 10 m/s, 3 m is not.
    v.check(PositionTarget(1, 0, -2), now=0.1)
    with pytest.raises(TargetRefused) as e:
        v.check(PositionTarget(3, 0, -2), now=0.1)
    assert e.value.reason == "too_fast"
    # A stale reference: the vehicle's position is used with a 1 s window.
    with pytest.raises(TargetRefused):
        v.check(PositionTarget(4, 4, -2), now=5.0, vehicle_position=(-5, -5, 0))
    v.check(PositionTarget(4, 4, -2), now=5.0, vehicle_position=(0, 0, -2))


def _refusal(fn) -> TargetRefused:
    with pytest.raises(TargetRefused) as e:
        fn()
    return e.value


@pytest.mark.parametrize("reason,refuse,words", [
    ("type", lambda v: v.check("up", now=0.0), ["str", "PositionTarget or VelocityTarget"]),
    ("non_finite", lambda v: v.check(PositionTarget(math.nan, 0, -2), now=0.0), ["non-finite", "x=nan"]),
    ("too_fast", lambda v: v.check(VelocityTarget(20, 0, 0), now=0.0), ["velocity 20.0 m/s", "max_speed 10 m/s"]),
    ("geofence", lambda v: v.check(PositionTarget(200, 0, -2), now=0.0),
     ["PositionTarget(x=200", "200.0 m from origin", "radius 100 m"]),
    ("geofence", lambda v: v.check(PositionTarget(0, 0, -80), now=0.0), ["altitude 80.0 m", "ceiling 50 m"]),
    ("no_reference", lambda v: v.check(PositionTarget(1, 0, -2), now=0.0, vehicle_position=(math.nan, 0.0, -2.0)),
     ["reference position (nan", "not finite"]),
    ("too_fast", lambda v: (v.accept(PositionTarget(0, 0, -2), now=0.0), v.check(PositionTarget(3, 0, -2), now=0.1)),
     ["jumps 3.0 m in 0.10 s", "30.0 m/s > max_speed 10 m/s"]),
    ("no_position", lambda v: v.check_against_vehicle(PositionTarget(1, 2, -3), None, max_offset_m=10),
     ["vehicle position unknown", "(1.0, 2.0, -3.0)", "LOCAL_POSITION_NED"]),
    ("jump", lambda v: v.check_against_vehicle(PositionTarget(12, 0, -3),
                                               VehicleMotion((0, 0, -3), (1, 0, 0)), max_offset_m=10),
     ["jump 12.0 m from vehicle position > 11 m", "max_offset_m 10 + 1 s at 1.0 m/s", "target (12.0, 0.0, -3.0)",
      "vehicle at (0.0, 0.0, -3.0)"]),
    ("too_fast", lambda v: v.check_against_vehicle(VelocityTarget(0, 6, 0), None, max_offset_m=10, max_speed=5),
     ["velocity 6.0 m/s", "max_speed 5 m/s"]),
    ("non_finite", lambda v: v.check_against_vehicle(VelocityTarget(0, 0, 1, yaw=math.inf), None, max_offset_m=10),
     ["non-finite", "yaw=inf"]),
])
def test_each_refusal_names_what_and_why(reason: str, refuse, words: list[str]) -> None:
    """One validator, one refusal type: the reason is the machine-readable code, the message
    (what the sender is told) names the target or value and the limit it broke."""
    v = TargetValidator(Geofence(max_distance_m=100, max_altitude_m=50), max_speed=10)
    e = _refusal(lambda: refuse(v))
    assert e.reason == reason
    for w in words:
        assert w in str(e), (w, str(e))


def test_check_against_vehicle_accepts_a_target_near_a_moving_vehicle() -> None:
    v = TargetValidator(max_speed=10)
    moving = VehicleMotion((0, 0, -3), (4, 0, 0))
    v.check_against_vehicle(PositionTarget(13.5, 0, -3), moving, max_offset_m=10)   # 10 m + 1 s at 4 m/s
    v.check_against_vehicle(VelocityTarget(9, 0, 0), None, max_offset_m=10)         # no position needed


def _sender(acks: list[int | None]):
    """CommandSender whose 'vehicle' answers the n-th send with acks[n] (None = silence)."""
    sent: list[tuple[int, int]] = []

    def send(command, params, confirmation):
        sent.append((command, confirmation))
        result = acks[len(sent) - 1] if len(sent) <= len(acks) else None
        if result is not None:
            threading.Timer(0.01, sender.handle_ack, (command, result)).start()

    sender = cmds.CommandSender(send, timeout=0.1, retries=2)
    return sender, sent


@pytest.mark.parametrize("result,exc", [
    (cmds.MAV_RESULT_DENIED, cmds.CommandDenied),
    (cmds.MAV_RESULT_TEMPORARILY_REJECTED, cmds.CommandTemporarilyRejected),
    (cmds.MAV_RESULT_UNSUPPORTED, cmds.CommandUnsupported),
    (cmds.MAV_RESULT_FAILED, cmds.CommandFailed),
])
def test_command_results_map_to_exceptions(result: int, exc: type) -> None:
    sender, _ = _sender([result])
    with pytest.raises(exc) as e:
        sender.run(400, [1])
    assert isinstance(e.value, cmds.CommandError) and e.value.result == result


def test_command_retries_then_succeeds_and_times_out() -> None:
    sender, sent = _sender([None, None, cmds.MAV_RESULT_ACCEPTED])
    ack = sender.run(176, [1, 6])
    assert ack.attempts == 3 and [c for _, c in sent] == [0, 1, 2]  # confirmation increments
    sender, sent = _sender([])
    with pytest.raises(cmds.CommandTimeout):
        sender.run(400, [1])
    assert len(sent) == 3


def test_parser_counts_garbage_and_bad_crc() -> None:
    frames: list[bytes] = []
    enc = Encoder(frames.append, 1, 1)
    enc.send(enc.heartbeat_encode(2, 12, 0, 0, 3))
    good = frames[0]
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    p = Parser()
    assert p.feed(b"\x00\x01garbage!!", datagram=True) == []
    assert p.feed(bytes(bad_crc), datagram=True) == []
    assert p.feed(good[:7], datagram=True) == []           # truncated frame
    msgs = p.feed(good, datagram=True)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT"]
    assert p.crc_errors == 1 and p.bad_frames >= 3 and p.bad_bytes > 10


def test_param_bytewise_int_encoding_roundtrips() -> None:
    for v in (0, 1, 5, 7, 255, -1, 21196):
        assert float_bits_to_int(int_to_float_bits(v)) == v


def test_imu_decodes_sensor_combined_fields() -> None:
    frames: list[bytes] = []
    enc = Encoder(frames.append, 3, 1)
    enc.send(enc.highres_imu_encode(123456, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4,
                                    955.0, 0.0, 488.5, 25.0, 0x1FFF, 0))
    m = Parser().feed(frames[0])[0]
    imu = Imu.from_mavlink(m)
    assert imu.timestamp_us == 123456 and imu.system_id == 3
    assert imu.accelerometer_m_s2 == pytest.approx((0.1, 0.2, -9.8))
    assert imu.gyro_rad == pytest.approx((0.01, 0.02, 0.03))
    assert imu.baro_alt_meter == pytest.approx(488.5) and imu.baro_temp_celcius == 25.0


def test_rate_below_10hz_refused() -> None:
    from px4_link import Px4Link
    with pytest.raises(ValueError):
        Px4Link("udpin:127.0.0.1:0", setpoint_rate_hz=5)


class _FakeCore:
    """Just what ``Offboard.outgoing`` touches: the latest position, counters and events."""

    def __init__(self, position: tuple[float, float, float]) -> None:
        from px4_link.telemetry import LocalPosition
        self.lp = LocalPosition(0, *position, 0.0, 0.0, 0.0)
        self.counts: dict[str, int] = {}
        self.events: list[str] = []

    def latest(self, kind):
        return self.lp

    def count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def emit(self, name: str, details: dict) -> None:
        self.events.append(name)

    def add_periodic(self, hook) -> None: ...
    def add_mode_hook(self, hook) -> None: ...


def test_offboard_fences_each_send_and_expires_velocity_once_per_episode() -> None:
    import time as _time

    from px4_link.offboard import Offboard
    core = _FakeCore((100.0, 0.0, -5.0))   # at the fence
    ob = Offboard(core, Geofence(max_distance_m=100), max_speed=10, velocity_timeout_s=1.0)  # type: ignore[arg-type]
    now = _time.monotonic()
    core.lp = type(core.lp)(0, 100.0, 0.0, -5.0, 0.0, 0.0, 0.0, received_at=now)
    out = VelocityTarget(4, 0, 0)
    ob.setpoint, ob._set_at = out, now
    for k in range(5):                                   # five sends, one episode
        assert ob.outgoing(out, now + 0.05 * k) == VelocityTarget(0, 0, 0)
    assert core.events == ["setpoint_clamped"] and core.counts == {"setpoints_clamped": 1}
    assert ob.outgoing(VelocityTarget(-4, 0, 0), now) == VelocityTarget(-4, 0, 0)   # back in: episode over
    ob.outgoing(out, now)
    assert core.counts["setpoints_clamped"] == 2
    back = VelocityTarget(-2, 1, 0)
    ob.setpoint, ob._set_at = back, now
    assert ob.outgoing(back, now + 1.5) == VelocityTarget(0, 0, 0)   # not refreshed: zero
    assert ob.outgoing(back, now + 1.6) == VelocityTarget(0, 0, 0)
    assert core.counts["setpoints_expired"] == 1
    assert ob.outgoing(PositionTarget(1, 2, -3), now + 9) == PositionTarget(1, 2, -3)   # a place never expires


def test_the_second_ack_of_a_mode_request_never_answers_the_next_one() -> None:
    """PX4 ACKs every DO_SET_MODE twice (px4_traces: 9 of 9, 0-8 ms apart). A refused request
    followed at once by another: the refusal's echo must not answer the second request."""
    import threading as _threading
    import time

    from px4_link.commands import CommandSender, CommandTemporarilyRejected
    MAV_CMD_DO_SET_MODE = 176

    sent: list[int] = []
    sender: CommandSender

    def send(command: int, params: object, confirmation: int) -> None:
        sent.append(command)
        n = len(sent)

        def answer() -> None:
            if n == 1:       # the first request: refused; its echo comes only after the caller moved on
                sender.handle_ack(command, 1)
            else:            # PX4's echo of the refusal reaches us first, then the second's answers
                sender.handle_ack(command, 1)
                time.sleep(0.005)
                sender.handle_ack(command, 0)
                sender.handle_ack(command, 0)
        _threading.Thread(target=answer, daemon=True).start()

    sender = CommandSender(send, timeout=1.0, retries=0)
    with pytest.raises(CommandTemporarilyRejected):
        sender.run(MAV_CMD_DO_SET_MODE, (1, 6))
    ack = sender.run(MAV_CMD_DO_SET_MODE, (1, 4))
    assert ack.result == 0 and len(sent) == 2
    assert sender.echoes == 1
