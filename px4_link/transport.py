"""Byte transports behind a pymavlink-style connection string.

``udpin:HOST:PORT`` (also ``udp:``) is implemented here rather than with mavutil because
the link needs to choose whom to answer: mavutil's UDP server replies to every address it
ever heard from, so after a simulator restart on a new source port (or a stray sender) it
would keep spraying packets at dead peers. We reply to the address the vehicle last spoke
from. Everything else (udpout, tcp, serial "/dev/ttyACM0,921600", ...) goes to mavutil.
"""
from __future__ import annotations

import errno
import select
import socket
from typing import Any, Protocol

from .connection_url import DEFAULT_BAUD, parse_px4_url

Address = tuple[str, int]


class Transport(Protocol):
    datagram: bool
    down_reason: str | None   # why the transport cannot carry bytes now (a vanished device); None: it can

    def recv(self, timeout: float) -> tuple[bytes, Address | None] | None: ...
    def write(self, data: bytes) -> None: ...
    def set_peer(self, addr: Address | None) -> None: ...
    def close(self) -> None: ...
    @property
    def local_address(self) -> Address | None: ...


class UdpServerTransport:
    """Bound UDP socket; answers the peer chosen with set_peer (the vehicle)."""

    datagram = True
    down_reason: str | None = None

    def __init__(self, host: str, port: int) -> None:
        # No SO_REUSEADDR: on UDP it would let a second process bind this port beside the first (a stale
        # companion, another program), and the vehicle's datagrams and its replies would cross between them
        # (two links locked on one vehicle). UDP has no TIME_WAIT: a restart binds again at once without it.
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        self.peer: Address | None = None
        self._first_sender: Address | None = None

    @property
    def local_address(self) -> Address:
        host, port = self.sock.getsockname()
        return host, port

    def recv(self, timeout: float) -> tuple[bytes, Address | None] | None:
        try:
            r, _, _ = select.select([self.sock], [], [], timeout)
        except (OSError, ValueError):
            return None
        if not r:
            return None
        try:
            data, addr = self.sock.recvfrom(65535)
        except OSError as e:
            if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return None
            raise
        if self._first_sender is None:
            self._first_sender = addr
        return data, addr

    def set_peer(self, addr: Address | None) -> None:
        self.peer = addr

    def write(self, data: bytes) -> None:
        peer = self.peer or self._first_sender
        if peer is None:
            return  # nobody heard yet: PX4 talks first on its offboard link
        try:
            self.sock.sendto(data, peer)
        except OSError:
            pass  # a vanished peer must not kill the sender; the watchdog will notice

    def close(self) -> None:
        self.sock.close()


class MavutilTransport:
    """Any other pymavlink connection string, using mavutil only for its byte I/O."""

    down_reason: str | None = None

    def __init__(self, connection: str, baud: int) -> None:
        from pymavlink import mavutil  # imported lazily: only needed for these transports

        self.conn: Any = mavutil.mavlink_connection(connection, baud=baud, autoreconnect=True)
        self.datagram = connection.startswith(("udpout:", "udpbcast:"))

    @property
    def local_address(self) -> Address | None:
        port = getattr(self.conn, "port", None)
        try:
            return port.getsockname() if port is not None else None
        except (OSError, AttributeError):
            return None

    def recv(self, timeout: float) -> tuple[bytes, Address | None] | None:
        try:
            if not self.conn.select(timeout):
                return None
            data = self.conn.recv(65535)
        except (OSError, ValueError):
            return None
        if not data:
            return None
        if isinstance(data, str):
            data = data.encode("latin-1")
        return bytes(data), None

    def set_peer(self, addr: Address | None) -> None:
        pass  # mavutil handles its own addressing

    def write(self, data: bytes) -> None:
        try:
            self.conn.write(data)
        except OSError:
            pass

    def close(self) -> None:
        try:
            self.conn.close()
        except Exception:
            pass


def open_transport(connection: str, baud: int = DEFAULT_BAUD) -> Transport:
    """``connection`` in any form ``connection_url`` reads (``baud``: when a serial one names none).
    Raises ``Px4UrlError`` (a ValueError) for a form it does not know, ConnectionError for a device
    that will not open."""
    url = parse_px4_url(connection, default_baud=baud)
    if url.kind == "udpin":
        return UdpServerTransport(url.host, url.port)
    if url.is_serial:
        from .serial_port import SerialTransport
        return SerialTransport(url)
    return MavutilTransport(url.pymavlink(), baud)
