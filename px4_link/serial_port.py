"""PX4 on a serial port (a UART on TELEM2, or USB), as a transport that outlives the device.

A USB flight controller's ``/dev/ttyACM0`` vanishes whenever PX4 reboots or the cable moves, and
comes back (possibly seconds later, possibly as another node behind the same ``/dev/serial/by-id``
link). So the port never ends the link: a read that finds the device gone (EOF, EIO) or a path
that now names another device closes it and records why (``down_reason``); every ``recv`` while it
is down tries the path again, at most every ``reopen_s``, and the wire counts as back with its first
bytes (a node that opens and hangs up at once, as a half-gone device can, is no return). The core
turns ``down_reason`` into the ``disconnected`` state at once instead of waiting out the heartbeat
watchdog.

Reads and writes use the descriptor pyserial opened non-blocking and configured (rate, raw mode,
an exclusive lock): a write the driver cannot take whole is dropped and counted, never waited for,
because the send thread also carries the offboard stream and the heartbeat.
"""
from __future__ import annotations

import errno
import os
import select
import threading
import time
from typing import Any

from .connection_url import DEFAULT_BAUD, Px4Url

Address = tuple[str, int]


def open_error(device: str, exc: BaseException) -> str:
    """One line for why ``device`` does not open, naming the fix where there is one."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT:
        return f"no serial device {device}: is the flight controller plugged in and powered?"
    if code in (errno.EACCES, errno.EPERM):
        return (f"permission denied on {device}: add the user to the dialout group "
                "(sudo usermod -aG dialout $USER, then log in again)")
    if code in (errno.EBUSY, errno.EWOULDBLOCK) or "lock" in str(exc).lower():
        return (f"{device} is in use by another program (another companion, mavlink-router, ModemManager?); "
                "share one port through mavlink-router")
    return f"cannot open {device}: {exc}"


class SerialTransport:
    """``transport.Transport`` over a serial device; see the module docstring."""

    datagram = False
    local_address: Address | None = None

    def __init__(self, url: Px4Url, *, reopen_s: float = 0.25, check_s: float = 0.5) -> None:
        import serial  # pyserial, the drone extra: imported only when a serial port is asked for

        self._serial: Any = serial
        self.url = url
        self.reopen_s = reopen_s
        self.check_s = check_s
        self._lock = threading.Lock()   # the port is swapped on the receive thread, written on others
        self._port: Any = None
        self._node: tuple[int, int] | None = None   # (st_rdev, st_ino) of what we opened
        self._next_try = 0.0
        self._next_check = 0.0
        self.down_reason: str | None = None
        self.opens = 0
        self.losses = 0
        self.tx_dropped = 0     # writes the driver could not take whole (bytes dropped, not queued)
        self._closed = False
        failure = self._try_open()
        if failure is not None:
            raise ConnectionError(failure)

    @property
    def baud(self) -> int:
        return self.url.baud

    # ----------------------------------------------------------------- opening and losing the device
    def _try_open(self) -> str | None:
        device = self.url.device
        try:
            port = self._serial.Serial(device, self.url.baud, timeout=0, write_timeout=0,
                                       rtscts=self.url.flow_control, exclusive=True)
            node = self._stat(device)
        except (OSError, ValueError) as exc:   # pyserial's SerialException is an OSError
            return open_error(device, exc)
        with self._lock:
            self._port, self._node = port, node
        self.opens += 1
        return None

    @staticmethod
    def _stat(device: str) -> tuple[int, int] | None:
        try:
            st = os.stat(device)
        except OSError:
            return None
        return st.st_rdev, st.st_ino

    def _lose(self, why: str) -> None:
        with self._lock:
            port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, ValueError):
                pass
        if self.down_reason is None:
            self.losses += 1
        self.down_reason = why
        self._next_try = time.monotonic() + self.reopen_s

    def _reopen(self, timeout: float) -> None:
        now = time.monotonic()
        if now >= self._next_try and not self._closed:
            self._next_try = now + self.reopen_s
            if os.path.exists(self.url.device):
                failure = self._try_open()
                if failure is None:
                    return
                self.down_reason = failure   # e.g. udev has not yet given the new node its group
        time.sleep(min(timeout, max(0.0, self._next_try - time.monotonic())))

    def _still_the_device(self, now: float) -> bool:
        """The path may name another node now (replugged, a by-id link repointed) with our old one
        still open and silent; a changed or missing node is a loss."""
        if now < self._next_check:
            return True
        self._next_check = now + self.check_s
        return self._stat(self.url.device) == self._node

    # ----------------------------------------------------------------- Transport
    def recv(self, timeout: float) -> tuple[bytes, Address | None] | None:
        port = self._port
        if port is None:
            self._reopen(timeout)
            return None
        device = self.url.device
        try:
            fd = port.fileno()
            ready, _, _ = select.select([fd], [], [], timeout)
        except (OSError, ValueError):
            if self._port is port:
                self._lose(f"serial device {device} closed under the link")
            return None
        if not ready:
            if not self._still_the_device(time.monotonic()):
                self._lose(f"serial device {device} replaced (replugged, or its link points elsewhere)")
            return None
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            return None
        except OSError as exc:
            self._lose(f"serial device {device} failed ({exc.strerror or exc}): unplugged, or PX4 rebooted")
            return None
        if not data:
            self._lose(f"serial device {device} vanished: unplugged, or PX4 rebooted")
            return None
        self.down_reason = None
        return data, None

    def write(self, data: bytes) -> None:
        with self._lock:
            port = self._port
            if port is None:
                self.tx_dropped += len(data)
                return
            try:
                n = os.write(port.fileno(), data)
            except BlockingIOError:
                n = 0
            except (OSError, ValueError):
                n = 0   # the receive thread finds the device gone and records why
        if n < len(data):
            self.tx_dropped += len(data) - n

    def set_peer(self, addr: Address | None) -> None:
        pass   # one wire, one peer

    def close(self) -> None:
        self._closed = True
        with self._lock:
            port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, ValueError):
                pass


class BaudCheck:
    """Bytes arrive but no MAVLink frame parses: the port's rate is not the sender's.

    At the wrong rate a UART still delivers bytes (framing errors become bytes too), but no frame's
    CRC ever checks out; at the right rate even a noisy line parses a frame within a few hundred
    bytes (the longest MAVLink 2 frame is 280). So ``threshold`` bytes without one frame is the
    verdict, said once per episode; a frame clears it.
    """

    def __init__(self, device: str, baud: int, threshold: int = 2048) -> None:
        self.device = device
        self.baud = baud
        self.threshold = threshold
        self._frames = 0
        self._since = 0           # bytes_total at the last frame
        self.suspect: str | None = None
        self.episodes = 0

    def update(self, bytes_total: int, frames_total: int) -> str | None:
        """The parser's running totals; the verdict the first time it holds in an episode, else None."""
        if frames_total != self._frames:
            self._frames = frames_total
            self._since = bytes_total
            self.suspect = None
            return None
        if self.suspect is not None or bytes_total - self._since < self.threshold:
            return None
        self.episodes += 1
        self.suspect = (f"bytes arrive on {self.device} but no MAVLink frame parses at {self.baud}: "
                        f"try {suggest_baud(self.baud)} (or the port runs no MAVLink: PX4's MAV_1_CONFIG, "
                        "SER_TEL2_BAUD)")
        return self.suspect


def suggest_baud(baud: int) -> str:
    # The two rates PX4 ships: TELEM2 (the companion's port) and TELEM1 (the SiK radio's).
    if baud != DEFAULT_BAUD:
        return f"{DEFAULT_BAUD} (PX4's TELEM2 default)"
    return "57600 (PX4's TELEM1 and SiK radio default)"
