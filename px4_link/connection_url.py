"""Where PX4 is: one parser for every connection form the link accepts.

Users arrive with MAVSDK's URLs (``serial:///dev/ttyACM0:57600``, ``udpin://0.0.0.0:14540``),
MAVROS's ``fcu_url`` (``/dev/ttyACM0:921600``) or pymavlink's strings (``udpin:127.0.0.1:14540``,
``/dev/ttyUSB0,57600``); all of them mean the same few things, so they are read here into one
``Px4Url`` and nothing else in the link looks at the text. A string that is none of them is a
``Px4UrlError`` naming the forms, never a guess: pymavlink takes any unknown word for a serial
device and fails deep inside pyserial.
"""
from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from typing import Literal

# PX4's TELEM2 (the companion port, MAV_1_CONFIG = TELEM 2) runs at SER_TEL2_BAUD = 921600 by default;
# USB ignores the rate. MAVSDK's own default (57600) is the SiK radio's rate on TELEM1: a companion
# given it on TELEM2 would see only garbage, so the link's default is PX4's, and a URL may say otherwise.
DEFAULT_BAUD = 921600

# The rates a UART on a flight controller or a companion computer is set to; anything else is a typo.
BAUD_RATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 921600, 1000000, 1500000,
              2000000, 3000000)

FORMS = ("/dev/ttyACM0[:BAUD]", "serial:///dev/ttyAMA0[:BAUD]", "udpin://HOST:PORT", "udp://[HOST]:PORT",
         "udpout://HOST:PORT", "tcp://HOST:PORT", "tcpin://HOST:PORT", "udpin:HOST:PORT (pymavlink)")

Kind = Literal["serial", "udpin", "udpout", "tcp", "tcpin"]


class Px4UrlError(ValueError):
    """Not a connection PX4 can be reached on; the text is one line naming the forms accepted.
    ``unknown_form``: no form at all (a caller with forms of its own may name those too)."""

    def __init__(self, text: str, unknown_form: bool = False) -> None:
        super().__init__(text)
        self.unknown_form = unknown_form


@dataclass(frozen=True)
class Px4Url:
    kind: Kind
    device: str = ""          # serial: the path (``/dev/serial/by-id/...`` is a path like any other)
    baud: int = DEFAULT_BAUD
    flow_control: bool = False   # serial: RTS/CTS (MAVSDK's ``serial_flowcontrol://``)
    host: str = ""
    port: int = 0

    @property
    def is_serial(self) -> bool:
        return self.kind == "serial"

    def pymavlink(self) -> str:
        """The string pymavlink's ``mavlink_connection`` reads (network kinds only)."""
        if self.is_serial:
            return f"{self.device},{self.baud}"
        return f"{self.kind}:{self.host}:{self.port}"

    def __str__(self) -> str:
        if self.is_serial:
            return f"{self.device} at {self.baud} baud" + (" (RTS/CTS)" if self.flow_control else "")
        return self.pymavlink()


def forms_line() -> str:
    return "expected one of: " + ", ".join(FORMS) + f" (default baud {DEFAULT_BAUD}, PX4's TELEM2)"


def parse_px4_url(spec: str, default_baud: int = DEFAULT_BAUD) -> Px4Url:
    """``spec`` as a ``Px4Url``; ``Px4UrlError`` (one line) if it is no form we know."""
    text = spec.strip()
    if not text:
        raise Px4UrlError(f"empty PX4 connection; {forms_line()}")
    scheme, sep, rest = text.partition("://")
    if sep:
        return _parse_url(text, scheme.lower(), rest, default_baud)
    if text.startswith("/") or re.fullmatch(r"COM\d+(:\d+)?", text, re.IGNORECASE):
        return _serial(text, text, default_baud, flow_control=False)
    kind, sep, rest = text.partition(":")
    if sep and kind in ("udpin", "udp", "udpout", "tcp", "tcpin"):
        # pymavlink's own strings, as the link has always taken them ("udp:" listens, as in pymavlink)
        host, port = _host_port(text, rest, allow_empty_host=False)
        return Px4Url("udpin" if kind == "udp" else kind, host=host, port=port)   # type: ignore[arg-type]
    raise Px4UrlError(f"{spec!r} is not a PX4 connection; {forms_line()}", unknown_form=True)


def _parse_url(spec: str, scheme: str, rest: str, default_baud: int) -> Px4Url:
    if scheme in ("serial", "serial_flowcontrol"):
        if not rest.startswith("/") and not re.fullmatch(r"COM\d+(:\d+)?", rest, re.IGNORECASE):
            raise Px4UrlError(f"{spec!r}: a serial URL names a device, as serial:///dev/ttyACM0:921600")
        return _serial(spec, rest, default_baud, flow_control=scheme == "serial_flowcontrol")
    if scheme in ("udp", "udpin"):
        # MAVSDK's udp://[HOST]:PORT (v1) and udpin:// (v2) both listen; no host: every interface.
        host, port = _host_port(spec, rest, allow_empty_host=True)
        return Px4Url("udpin", host=host or "0.0.0.0", port=port)
    if scheme in ("udpout", "tcp", "tcpout", "tcpin"):
        host, port = _host_port(spec, rest, allow_empty_host=scheme == "tcpin")
        kind: Kind = "tcpin" if scheme == "tcpin" else "udpout" if scheme == "udpout" else "tcp"
        return Px4Url(kind, host=host or "0.0.0.0", port=port)
    raise Px4UrlError(f"{spec!r}: unknown scheme {scheme}://; {forms_line()}", unknown_form=True)


def _serial(spec: str, text: str, default_baud: int, *, flow_control: bool) -> Px4Url:
    device, baud = text, default_baud
    # MAVROS and MAVSDK put the rate after a colon, pymavlink after a comma; a path has neither.
    m = re.fullmatch(r"(.+?)[:,](\d*)", text)
    if m is not None and not os.path.exists(text):   # by-path names hold colons: a real path wins
        device, digits = m.group(1), m.group(2)
        if not digits:
            raise Px4UrlError(f"{spec!r}: the baud rate after {device!r} is missing")
        baud = int(digits)
    if baud not in BAUD_RATES:
        raise Px4UrlError(f"{spec!r}: {baud} is not a serial baud rate; one of {', '.join(map(str, BAUD_RATES))}")
    if device.endswith("/") or "\x00" in device:
        raise Px4UrlError(f"{spec!r}: {device!r} is not a device path")
    return Px4Url("serial", device=device, baud=baud, flow_control=flow_control)


def _host_port(spec: str, rest: str, *, allow_empty_host: bool) -> tuple[str, int]:
    host, sep, port = rest.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]   # an IPv6 literal, [::1]
    if not sep or not port.isdigit() or int(port) > 65535:
        raise Px4UrlError(f"{spec!r}: expected HOST:PORT with a port 0..65535; {forms_line()}")
    if not host and not allow_empty_host:
        raise Px4UrlError(f"{spec!r}: the host is missing (e.g. 127.0.0.1:{port})")
    return host, int(port)


def check_serial_device(url: Px4Url) -> None:
    """Before a serial link opens: ``Px4UrlError`` naming the fix if its device is missing or not ours
    to open (a companion started by a user outside the ``dialout`` group, the common first mistake)."""
    if not url.is_serial or url.device.upper().startswith("COM"):
        return
    path = url.device
    if not os.path.exists(path):
        hint = ("is the flight controller plugged in and powered? `ls /dev/serial/by-id/` lists USB ones"
                if "tty" in path or "serial" in path else "no such file")
        raise Px4UrlError(f"no serial device {path}: {hint}")
    if not os.access(path, os.R_OK | os.W_OK):
        raise Px4UrlError(f"permission denied on {path}: add the user to the dialout group "
                          "(sudo usermod -aG dialout $USER, then log in again)")
    if not stat.S_ISCHR(os.stat(path).st_mode):
        raise Px4UrlError(f"{path} is not a serial device (a tty such as /dev/ttyACM0 or /dev/ttyAMA0)")
