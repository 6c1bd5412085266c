"""Where PX4 is (px4_link/connection_url.py) and how a wrong serial rate is named (serial_port.BaudCheck):
pure functions on strings and byte streams."""
from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from px4_link.connection_url import DEFAULT_BAUD, Px4Url, Px4UrlError, check_serial_device, parse_px4_url
from px4_link.serial_port import BaudCheck, open_error
from px4_link.wire import Encoder, Parser, mavlink2

pytestmark = pytest.mark.fast


@pytest.mark.parametrize(("spec", "expected"), [
    ("/dev/ttyACM0", Px4Url("serial", device="/dev/ttyACM0", baud=DEFAULT_BAUD)),
    ("/dev/ttyAMA0:921600", Px4Url("serial", device="/dev/ttyAMA0", baud=921600)),
    ("/dev/ttyUSB0,57600", Px4Url("serial", device="/dev/ttyUSB0", baud=57600)),          # pymavlink's comma
    ("/dev/serial/by-id/usb-Auterion_PX4_FMU_v6X.x_0-if00",
     Px4Url("serial", device="/dev/serial/by-id/usb-Auterion_PX4_FMU_v6X.x_0-if00")),
    ("serial:///dev/ttyACM0:57600", Px4Url("serial", device="/dev/ttyACM0", baud=57600)),  # MAVSDK
    ("serial:///dev/ttyTHS1", Px4Url("serial", device="/dev/ttyTHS1")),
    ("serial_flowcontrol:///dev/ttyS1:115200", Px4Url("serial", device="/dev/ttyS1", baud=115200, flow_control=True)),
    ("udp://:14540", Px4Url("udpin", host="0.0.0.0", port=14540)),                         # MAVSDK v1
    ("udp://192.168.1.5:14540", Px4Url("udpin", host="192.168.1.5", port=14540)),
    ("udpin://0.0.0.0:14540", Px4Url("udpin", host="0.0.0.0", port=14540)),                # MAVSDK v2
    ("udpout://10.0.0.2:14557", Px4Url("udpout", host="10.0.0.2", port=14557)),
    ("tcp://127.0.0.1:5760", Px4Url("tcp", host="127.0.0.1", port=5760)),
    ("tcpout://127.0.0.1:5760", Px4Url("tcp", host="127.0.0.1", port=5760)),
    ("tcpin://:5760", Px4Url("tcpin", host="0.0.0.0", port=5760)),
    ("udpin:127.0.0.1:14540", Px4Url("udpin", host="127.0.0.1", port=14540)),              # as always
    ("udpin:127.0.0.1:0", Px4Url("udpin", host="127.0.0.1", port=0)),
    ("udp:127.0.0.1:14540", Px4Url("udpin", host="127.0.0.1", port=14540)),
    ("udpout:127.0.0.1:14550", Px4Url("udpout", host="127.0.0.1", port=14550)),
    ("tcp:127.0.0.1:5760", Px4Url("tcp", host="127.0.0.1", port=5760)),
])
def test_every_form_users_bring(spec: str, expected: Px4Url) -> None:
    assert parse_px4_url(spec) == expected


def test_pymavlink_strings_round_trip() -> None:
    assert parse_px4_url("udpout://10.0.0.2:14557").pymavlink() == "udpout:10.0.0.2:14557"
    assert parse_px4_url("tcp://h:5760").pymavlink() == "tcp:h:5760"
    assert parse_px4_url("/dev/ttyACM0:57600").pymavlink() == "/dev/ttyACM0,57600"


def test_a_caller_default_baud_applies_when_the_spec_names_none() -> None:
    assert parse_px4_url("/dev/ttyACM0", default_baud=115200).baud == 115200
    assert parse_px4_url("/dev/ttyACM0:57600", default_baud=115200).baud == 57600


def test_a_path_with_colons_that_exists_is_a_path(tmp_path: Path) -> None:
    by_path = tmp_path / "pci-0000:00:14.0-usb-0:1:1"     # /dev/serial/by-path names end so
    by_path.touch()
    assert parse_px4_url(str(by_path)).device == str(by_path)


@pytest.mark.parametrize(("spec", "says"), [
    ("foo", "is not a PX4 connection; expected one of: /dev/ttyACM0[:BAUD], serial:///dev/ttyAMA0[:BAUD]"),
    ("", "empty"),
    ("ttyUSB0", "is not a PX4 connection"),
    ("/dev/ttyACM0:12345", "12345 is not a serial baud rate; one of 9600"),
    ("/dev/ttyACM0:", "baud rate after '/dev/ttyACM0' is missing"),
    ("serial://ttyACM0", "a serial URL names a device"),
    ("udp://:99999", "port 0..65535"),
    ("udpout://:14550", "the host is missing"),
    ("udpin:14540", "expected HOST:PORT"),
    ("http://px4:80", "unknown scheme http://"),
])
def test_anything_else_is_one_line_naming_the_forms(spec: str, says: str) -> None:
    with pytest.raises(Px4UrlError, match=None) as err:
        parse_px4_url(spec)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_missing_device_says_so(tmp_path: Path) -> None:
    with pytest.raises(Px4UrlError, match="no serial device /dev/ttyNOPE0: is the flight controller plugged in"):
        check_serial_device(parse_px4_url("/dev/ttyNOPE0"))


def test_a_device_we_may_not_open_names_the_dialout_group(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    device = tmp_path / "ttyACM0"
    device.touch()
    monkeypatch.setattr(os, "access", lambda *_: False)   # tests run as root here; a user is not
    with pytest.raises(Px4UrlError, match="add the user to the dialout group"):
        check_serial_device(parse_px4_url(str(device)))


def test_a_file_that_is_no_tty_is_not_a_serial_device(tmp_path: Path) -> None:
    (tmp_path / "notes").touch()
    for path in (tmp_path / "notes", tmp_path):
        with pytest.raises(Px4UrlError, match="is not a serial device"):
            check_serial_device(parse_px4_url(str(path)))
    check_serial_device(parse_px4_url("/dev/null"))   # a character device: opening it is the port's business


def test_open_errors_name_the_fix() -> None:
    assert "dialout" in open_error("/dev/ttyACM0", OSError(errno.EACCES, "Permission denied"))
    assert "no serial device" in open_error("/dev/ttyACM0", OSError(errno.ENOENT, "No such file"))
    assert "in use by another program" in open_error("/dev/ttyACM0", OSError(errno.EWOULDBLOCK, "lock"))


# -- the wrong rate, on byte streams ----------------------------------------------------------------

def frames(n: int) -> bytes:
    """``n`` of what PX4 sends: heartbeats and attitudes, as MAVLink 2 bytes."""
    out: list[bytes] = []
    enc = Encoder(out.append, 1, 1)
    for i in range(n):
        enc.send(enc.heartbeat_encode(2, 12, 1, 0, mavlink2.MAV_STATE_STANDBY))
        enc.send(enc.attitude_encode(i * 10, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
    return b"".join(out)


def uart(data: bytes, sent_at: int, read_at: int) -> bytes:
    """What a UART reading at ``read_at`` makes of 8N1 bytes sent at ``sent_at``: it waits for a start
    bit, samples each bit in the middle of its own bit time and resynchronises on the next start
    bit (edges are caught exactly; a real receiver's 16x oversampling is within 1/16 of a bit)."""
    bits: list[int] = [1] * 20
    for b in data:
        bits += [0, *((b >> i) & 1 for i in range(8)), 1]
    bits += [1] * 20
    step = sent_at / read_at          # sent bits per read bit
    out = bytearray()
    t = 0.0
    while t < len(bits):
        if bits[int(t)] == 1:
            t = int(t) + 1.0          # a falling edge falls on a sent bit's boundary: the next one
            continue
        centre = t + step / 2
        value = 0
        for i in range(8):
            pos = centre + step * (i + 1)
            value |= (bits[int(pos)] if pos < len(bits) else 1) << i
        out.append(value)
        t = centre + step * 9         # past the stop bit
    return bytes(out)


def verdict(stream: bytes, baud: int, chunk: int = 64) -> tuple[str | None, int]:
    """Feed ``stream`` in serial-sized reads: the detector's first verdict and the frames parsed."""
    parser, check = Parser(), BaudCheck("/dev/ttyAMA0", baud)
    said = None
    for i in range(0, len(stream), chunk):
        parser.feed(stream[i:i + chunk])
        said = check.update(parser.bytes_received, parser.messages) or said
    return said, parser.messages


def test_the_uart_model_passes_frames_at_the_right_rate() -> None:
    data = frames(40)
    assert uart(data, 921600, 921600) == data
    assert verdict(uart(data, 921600, 921600), 921600) == (None, 80)


@pytest.mark.parametrize(("sent_at", "read_at", "try_"), [
    (921600, 57600, "try 921600"), (57600, 921600, "try 57600"), (921600, 115200, "try 921600")])
def test_a_wrong_rate_is_named(sent_at: int, read_at: int, try_: str) -> None:
    stream = uart(frames(100 if read_at > sent_at else 1500), sent_at, read_at)
    said, parsed = verdict(stream, read_at)
    assert parsed == 0
    assert said is not None and f"no MAVLink frame parses at {read_at}: {try_}" in said


def test_noise_with_frames_in_it_is_not_a_wrong_rate() -> None:
    import random
    rng = random.Random(5)
    # A noisy line: 100 random bytes before each heartbeat and attitude (swallowing some of them)
    stream = b"".join(bytes(rng.randrange(256) for _ in range(100)) + frames(1) for _ in range(100))
    said, parsed = verdict(stream, 921600)
    assert said is None and parsed > 0


def test_the_verdict_is_said_once_per_episode_and_a_frame_ends_it() -> None:
    check = BaudCheck("/dev/ttyS0", 57600, threshold=100)
    assert check.update(150, 0) is not None
    assert check.update(400, 0) is None and check.suspect is not None    # said once
    assert check.update(420, 1) is None and check.suspect is None         # a frame: the rate is right
    assert check.update(600, 1) is not None and check.episodes == 2
