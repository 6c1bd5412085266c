"""QGroundControl alongside: PX4's MAVLink bytes over the drone's Zenoh session, and back under a policy.

``companion --mavlink-tunnel`` publishes what PX4 sends on ``<id>/mavlink/down`` and forwards what
arrives on ``<id>/mavlink/up`` (from ``gcs --mavlink-out``, i.e. from a QGC on the GCS machine) to PX4
only as far as the command policy lets it through. How it reaches PX4's bytes depends on the link:

- UDP (``udpin:HOST:PORT``): a UDP tee (``UdpTee``) sits where PX4 sends (its MAVLink port); every
  datagram from PX4 goes on to the companion's own link unchanged and is also published as it is.
- A serial port or USB (``/dev/ttyAMA0:921600``, ``serial:///dev/ttyACM0``): one wire, which the
  companion's link holds exclusively, so there is nothing to put a tee on; the tunnel taps the link
  itself (``LinkTap``): px4_link hands it the raw bytes of every frame it accepts from the vehicle,
  published grouped into datagrams (a few ms of frames, at most ``MAX_DATAGRAM``), and QGC's accepted
  frames are written through the link (``Px4Link.send_raw``), each whole, between the link's own frames.
  The serial line is the link's first: a frame from QGC that would hold up the link's own traffic
  (setpoints, heartbeat) is dropped and counted, never queued. Down, QGC sees the vehicle's frames
  in the companion's dialect (other systems' frames and message ids unknown to it stay on the wire).

Only what was judged reaches PX4: each datagram from QGC is parsed frame by frame (a fresh
parser per datagram, so no partial frame carries over into the next), and the frames the policy
accepts are re-encoded (their own sequence number, system and component id) and sent on; the
datagram itself never is. Bytes that are no frame, frames failing their CRC or flags, a partial
frame at the datagram's end and the refused frames are dropped and counted. Re-encoding also
drops payload bytes the companion's dialect does not know (extension fields it could not judge).
A signed frame is sent as received, signature included, when its payload is exactly the one
judged; otherwise it is re-encoded (unsigned).

Policy (safety first: the drone never moves unless an authorised operator asked, and
the companion is where that is decided): by default only read-only traffic goes up:
heartbeats, time sync, parameter and mission *reads*, and information requests.
Anything that could move or reconfigure the vehicle (arm, mode, setpoints, parameter
or mission writes, any other command) is refused, counted per message name, and the
refusal is reported to QGC: a COMMAND_ACK DENIED for a command, a STATUSTEXT
(rate-limited) otherwise. ``allow_control=True`` (``--mavlink-tunnel-allow-control``)
lets everything through, for a bench or a field operator who owns the vehicle.
"""
from __future__ import annotations

import contextlib
import logging
import select
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mavlink2

from drone_contract.tunnel import MAX_DATAGRAM, TUNNEL_DOWN, TUNNEL_QOS, TUNNEL_UP, MavlinkPacket
from px4_link.connection_url import parse_px4_url

log = logging.getLogger("companion.mavlink_tunnel")


# Read-only traffic a QGC needs to show a vehicle: always allowed up.
READ_ONLY = frozenset({
    "HEARTBEAT", "SYSTEM_TIME", "TIMESYNC", "PING",
    "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_EXT_REQUEST_LIST", "PARAM_EXT_REQUEST_READ",
    "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK",
    "LOG_REQUEST_LIST", "AUTOPILOT_VERSION_REQUEST",
})
# Commands that only ask for information.
READ_ONLY_COMMANDS = frozenset({
    mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAV_CMD_REQUEST_PROTOCOL_VERSION,
    mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mavlink2.MAV_CMD_REQUEST_CAMERA_INFORMATION,
    mavlink2.MAV_CMD_REQUEST_FLIGHT_INFORMATION, mavlink2.MAV_CMD_REQUEST_STORAGE_INFORMATION,
})
COMMANDS = frozenset({"COMMAND_LONG", "COMMAND_INT"})
STATUSTEXT_PERIOD = 2.0     # at most one refusal notice per this many seconds


@dataclass
class TunnelCounters:
    down: int = 0                 # datagrams from PX4 published
    up_forwarded: int = 0         # datagrams of accepted frames sent to PX4
    up_frames_forwarded: int = 0  # frames in them
    up_refused: int = 0           # datagrams holding at least one refused frame
    up_malformed: int = 0         # datagrams without one whole MAVLink frame
    up_bad_data: int = 0          # chunks dropped as no frame: bad prefix, failed CRC, bad flags, unknown id
    up_partial: int = 0           # datagrams ending in an incomplete frame (dropped)
    up_dropped_bytes: int = 0     # bytes from QGC that were not a judged frame (bad data, partial frames)
    up_frames_dropped: int = 0    # accepted frames PX4's side could not take now (serial line busy, PX4
                                  # not heard yet on UDP): dropped, never queued
    down_frames_dropped: int = 0  # serial: PX4 frames not published, the publisher fell behind
    refused_by_message: Counter[str] = field(default_factory=Counter)


@dataclass
class Judged:
    """One datagram from QGC, frame by frame."""
    accepted: list[Any] = field(default_factory=list)    # frames the policy lets through, in order
    refused: list[Any] = field(default_factory=list)     # frames it does not
    bad_data: int = 0             # BAD_DATA chunks
    partial: bool = False         # an incomplete frame at the end
    dropped_bytes: int = 0        # bytes of bad data and of the partial frame


def _parser() -> Any:
    """A fresh robust parser: one per datagram, so nothing of one datagram completes a frame of the next."""
    p = mavlink2.MAVLink(None)
    p.robust_parsing = True
    return p


def _payload(frame: bytes) -> bytes:
    header = 10 if frame[0] == mavlink2.PROTOCOL_MARKER_V2 else 6
    return frame[header:header + frame[1]]


def _signed(frame: bytes) -> bool:
    return frame[0] == mavlink2.PROTOCOL_MARKER_V2 and bool(frame[2] & mavlink2.MAVLINK_IFLAG_SIGNED)


class MavlinkPolicy:
    """Decides which frames of a datagram from QGC may reach PX4, and encodes them again.

    Stateless between datagrams (every call makes its own parser): safe from any thread.
    """

    def __init__(self, allow_control: bool = False) -> None:
        self.allow_control = allow_control

    def judge(self, data: bytes) -> Judged:
        """Split ``data`` into accepted and refused frames; count what is no frame at all."""
        parser = _parser()
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:   # pymavlink raised on something it could not even call bad data: trust nothing
            return Judged(bad_data=1, dropped_bytes=len(data))
        judged = Judged()
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                judged.bad_data += 1
                judged.dropped_bytes += len(m.get_msgbuf())
            elif self._allowed(m):
                judged.accepted.append(m)
            else:
                judged.refused.append(m)
        left = parser.buf_len()
        if left:
            judged.partial = True
            judged.dropped_bytes += left
        return judged

    def frames(self, data: bytes) -> list[Any]:
        """The whole frames in ``data`` (accepted or not)."""
        try:
            msgs = _parser().parse_buffer(data) or []
        except Exception:
            return []
        return [m for m in msgs if m.get_type() != "BAD_DATA"]

    def refused(self, msgs: list[Any]) -> list[Any]:
        """The frames that may not go up."""
        return [m for m in msgs if not self._allowed(m)]

    def _allowed(self, m: Any) -> bool:
        if self.allow_control:
            return True
        name = m.get_type()
        if name in READ_ONLY:
            return True
        return name in COMMANDS and getattr(m, "command", None) in READ_ONLY_COMMANDS

    @staticmethod
    def encode(m: Any) -> bytes:
        """``m`` packed again from its decoded fields, with its own seq, system and component id and wire version."""
        original = bytes(m.get_msgbuf())
        enc = mavlink2.MAVLink(None, srcSystem=m.get_srcSystem(), srcComponent=m.get_srcComponent())
        enc.seq = m.get_seq()
        fresh = bytes(m.pack(enc, force_mavlink1=original[0] == mavlink2.PROTOCOL_MARKER_V1))
        if _signed(original) and _payload(original) == _payload(fresh):
            return original   # exactly what was judged, and PX4 with signing still accepts it
        return fresh


class UdpTee:
    """Sits where PX4 sends: ``listen`` (PX4's target), relays to the link at ``link_port``.

    PX4 -> tee -> link, link -> tee -> PX4; every PX4 datagram also goes to ``on_down``.
    ``inject(data)`` sends to PX4 (for QGC's traffic). Behind the tee the link hears everything
    from one address, so the tee does the link's address lock for it: PX4 is the first address
    that sends to ``listen`` (it moves only after ``RELOCK_S`` of silence, a PX4 restart on a new
    port), and only the link's own socket may send to PX4 through the link side; datagrams from
    anyone else are dropped and counted in ``foreign``.
    """

    RELOCK_S = 3.0

    def __init__(self, listen: tuple[str, int], link_port: int, on_down: Callable[[bytes], None]) -> None:
        self.on_down = on_down
        self._px4_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._px4_side.bind(listen)
        self._link_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._link_side.bind(("127.0.0.1", 0))
        self._link_addr = ("127.0.0.1", link_port)
        self.px4_addr: tuple[str, int] | None = None
        self.relayed = 0
        self.callback_errors = 0
        self.foreign = 0
        self._px4_heard = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mavlink-tee", daemon=True)

    @property
    def port(self) -> int:
        return int(self._px4_side.getsockname()[1])

    def start(self) -> "UdpTee":
        self._thread.start()
        return self

    def inject(self, data: bytes) -> bool:
        if self.px4_addr is None:
            return False
        self._px4_side.sendto(data, self.px4_addr)
        return True

    def inject_frames(self, frames: list[bytes]) -> int:
        """QGC's judged frames to PX4 in one datagram, as QGC sent them together; how many went."""
        return len(frames) if self.inject(b"".join(frames)) else 0

    def _run(self) -> None:
        socks = [self._px4_side, self._link_side]
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select(socks, [], [], 0.2)
            except (OSError, ValueError):
                return
            for s in ready:
                try:
                    data, addr = s.recvfrom(MAX_DATAGRAM)
                except OSError:
                    continue
                if s is self._px4_side:
                    if not self._is_px4(addr):
                        self.foreign += 1
                        continue
                    self._link_side.sendto(data, self._link_addr)
                    self.relayed += 1
                    try:
                        self.on_down(data)
                    except Exception:
                        self.callback_errors += 1
                elif addr != self._link_addr:
                    self.foreign += 1   # a local process other than the link: never relayed to PX4
                elif self.px4_addr is not None:
                    self._px4_side.sendto(data, self.px4_addr)

    def _is_px4(self, addr: tuple[str, int]) -> bool:
        now = time.monotonic()
        if self.px4_addr is None or addr == self.px4_addr or now - self._px4_heard > self.RELOCK_S:
            self.px4_addr = addr
            self._px4_heard = now
            return True
        return False

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for s in (self._px4_side, self._link_side):
            s.close()


class RawLink(Protocol):
    """What the tap needs of the link to PX4 (``px4_link.Px4Link``)."""

    def add_frame_listener(self, listener: Callable[[bytes], None]) -> None: ...
    def send_raw(self, frame: bytes) -> bool: ...


class LinkTap:
    """PX4 on a serial port: the tunnel's end on the companion's own link (see the module docstring).

    Down: every frame the link accepts from the vehicle is queued here on the link's receive thread
    (which must never wait on Zenoh) and handed to ``on_down`` by the tap's thread in groups: one group
    per ``FLUSH_S`` after its first frame, or sooner when it reaches ``MAX_DATAGRAM`` bytes. At most
    ``MAX_PENDING`` bytes wait; past that frames are dropped and counted (``dropped``, ``on_drop``).
    Up: ``inject_frames`` writes each frame whole through ``link.send_raw``, which refuses rather than
    queues when the line is busy.
    """

    FLUSH_S = 0.004        # a frame waits at most this long for others to share its datagram
    MAX_PENDING = MAX_DATAGRAM

    def __init__(self, link: RawLink, on_down: Callable[[bytes], None] = lambda d: None) -> None:
        self.link = link
        self.on_down = on_down
        self.on_drop: Callable[[int], None] = lambda n: None   # frames dropped down (publisher behind)
        self.frames = 0             # frames from PX4 handed to on_down
        self.datagrams = 0          # groups handed to on_down
        self.dropped = 0            # frames from PX4 dropped: more than MAX_PENDING bytes waiting
        self.callback_errors = 0
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        self._first_at = 0.0
        self._closed = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="mavlink-tap", daemon=True)
        self._thread.start()
        link.add_frame_listener(self._on_frame)

    def _on_frame(self, frame: bytes) -> None:
        """The link's receive thread: queue, never wait, never raise."""
        with self._cond:
            if self._closed:
                return
            if self._pending_bytes + len(frame) > self.MAX_PENDING:
                self.dropped += 1
                dropped = True
            else:
                dropped = False
                if not self._pending:
                    self._first_at = time.monotonic()
                    self._cond.notify()
                self._pending.append(frame)
                self._pending_bytes += len(frame)
                if self._pending_bytes >= MAX_DATAGRAM:
                    self._cond.notify()   # a full datagram goes now, not at the end of the window
        if dropped:
            try:
                self.on_drop(1)
            except Exception:
                self.callback_errors += 1

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: bool(self._pending) or self._closed)
                if self._closed:
                    return
                deadline = self._first_at + self.FLUSH_S
                while self._pending_bytes < MAX_DATAGRAM and not self._closed:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
                frames, self._pending, self._pending_bytes = self._pending, [], 0
            for group in datagrams(frames):
                self.frames += len(group)
                self.datagrams += 1
                try:
                    self.on_down(b"".join(group))
                except Exception:
                    self.callback_errors += 1

    def inject_frames(self, frames: list[bytes]) -> int:
        """QGC's judged frames to PX4, each whole; how many went (the rest the line had no room for)."""
        return sum(1 for f in frames if self.link.send_raw(f))

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)


def datagrams(frames: list[bytes], limit: int = MAX_DATAGRAM) -> Iterator[list[bytes]]:
    """``frames`` in order, grouped so no group's bytes exceed ``limit`` (a frame is never split)."""
    group: list[bytes] = []
    size = 0
    for f in frames:
        if group and size + len(f) > limit:
            yield group
            group, size = [], 0
        group.append(f)
        size += len(f)
    if group:
        yield group


class Px4Side(Protocol):
    """The tunnel's end at PX4: ``UdpTee`` (UDP) or ``LinkTap`` (a serial port)."""

    on_down: Callable[[bytes], None]

    def inject_frames(self, frames: list[bytes]) -> int: ...
    def close(self) -> None: ...


class MavlinkTunnel:
    """The companion side: ``<id>/mavlink/down`` out, ``<id>/mavlink/up`` in through the policy."""

    def __init__(self, node: Any, tee: Px4Side, *, allow_control: bool = False,
                 sysid: int = 1, compid: int = 191) -> None:
        self.node = node
        self.tee = tee
        self.policy = MavlinkPolicy(allow_control)
        self.counters = TunnelCounters()
        self._down = node.create_publisher(MavlinkPacket, TUNNEL_DOWN, TUNNEL_QOS)
        self._up = node.create_subscription(MavlinkPacket, TUNNEL_UP, self._on_up, TUNNEL_QOS)
        self._reply = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._notice_at = 0.0
        self._logged_at = 0.0
        self._dropped_logged_at = 0.0
        self._busy_logged_at = 0.0
        tee.on_down = self.publish_down
        if isinstance(tee, LinkTap):
            tee.on_drop = self._down_dropped

    def publish_down(self, data: bytes) -> None:
        self._down.publish(MavlinkPacket(data))
        self.counters.down += 1

    def _on_up(self, pkt: MavlinkPacket) -> None:
        judged = self.policy.judge(bytes(pkt.data))
        c = self.counters
        c.up_bad_data += judged.bad_data
        c.up_partial += judged.partial
        c.up_dropped_bytes += judged.dropped_bytes
        if judged.dropped_bytes:
            self._log_dropped(judged)
        if not judged.accepted and not judged.refused:
            c.up_malformed += 1
            return
        if judged.refused:
            c.up_refused += 1
            for m in judged.refused:
                c.refused_by_message[m.get_type()] += 1
            self._report(judged.refused)
        if not judged.accepted:
            return
        sent = self.tee.inject_frames([self.policy.encode(m) for m in judged.accepted])
        if sent:
            c.up_forwarded += 1
            c.up_frames_forwarded += sent
        if sent < len(judged.accepted):
            c.up_frames_dropped += len(judged.accepted) - sent
            self._log_busy()

    def _down_dropped(self, n: int) -> None:
        self.counters.down_frames_dropped += n

    def _log_busy(self) -> None:
        now = time.monotonic()
        if now - self._busy_logged_at >= 10.0:
            self._busy_logged_at = now
            log.warning("MAVLink from the GCS: %d frames dropped so far, PX4's side could not take them "
                        "(a serial line busy with the companion's own traffic, or PX4 not heard yet)",
                        self.counters.up_frames_dropped)

    def _log_dropped(self, judged: Judged) -> None:
        now = time.monotonic()
        if now - self._dropped_logged_at >= 10.0:
            self._dropped_logged_at = now
            log.warning("MAVLink from the GCS: %d bytes that are no whole valid frame dropped (%d bad data, "
                        "%d partial frames so far)", judged.dropped_bytes, self.counters.up_bad_data,
                        self.counters.up_partial)

    def _report(self, refused: list[Any]) -> None:
        """Tell QGC (down the tunnel) why nothing happened: DENIED for commands, else a STATUSTEXT."""
        for m in refused:
            if m.get_type() in COMMANDS:
                ack = self._reply.command_ack_encode(m.command, mavlink2.MAV_RESULT_DENIED, 0, 0,
                                                     m.get_srcSystem(), m.get_srcComponent())
                self._down.publish(MavlinkPacket(bytes(ack.pack(self._reply))))
        now = time.monotonic()
        names = ", ".join(sorted({m.get_type() for m in refused}))
        if now - self._notice_at >= STATUSTEXT_PERIOD:
            self._notice_at = now
            text = f"companion: {names} refused (tunnel is read-only)"[:50].encode()
            st = self._reply.statustext_encode(mavlink2.MAV_SEVERITY_WARNING, text)
            self._down.publish(MavlinkPacket(bytes(st.pack(self._reply))))
        if now - self._logged_at >= 10.0:   # the log says it too, rate-limited
            self._logged_at = now
            log.warning("MAVLink from the GCS refused: %s (%d refused so far; --mavlink-tunnel-allow-control "
                        "lets QGC command the vehicle)", names, self.counters.up_refused)

    def close(self) -> None:
        self.tee.close()


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def tee_connection(connection: str, on_down: Callable[[bytes], None] = lambda d: None) -> tuple[UdpTee, str]:
    """Put a tee on a ``udpin:HOST:PORT`` connection: returns it and the link's new connection string."""
    kind, _, rest = connection.partition(":")
    host, _, port = rest.rpartition(":")
    if kind != "udpin" or not port.isdigit():
        raise ValueError(f"--mavlink-tunnel needs a udpin:HOST:PORT or serial PX4 connection, got {connection!r}")
    link_port = free_udp_port()
    tee = UdpTee((host, int(port)), link_port, on_down).start()
    return tee, f"udpin:127.0.0.1:{link_port}"


def is_serial(connection: str) -> bool:
    """Does ``connection`` name a serial port or USB device (the tunnel taps the link there, no tee)?"""
    try:
        return parse_px4_url(connection).is_serial
    except ValueError:
        return False


@contextlib.contextmanager
def maybe_tee(enabled: bool, connection: str) -> Iterator[tuple[UdpTee | None, str]]:
    """``(tee, link connection)`` with a tee on PX4's port when ``enabled``, else ``(None, connection)``;
    a serial connection gets no tee either: its tunnel is a ``LinkTap`` on the link (``maybe_tap``)."""
    if not enabled or is_serial(connection):
        yield None, connection
        return
    tee, link_connection = tee_connection(connection)
    try:
        yield tee, link_connection
    finally:
        tee.close()


@contextlib.contextmanager
def maybe_tap(enabled: bool, link: RawLink) -> Iterator[LinkTap | None]:
    """A ``LinkTap`` on ``link`` when ``enabled`` (a serial PX4 with ``--mavlink-tunnel``), else None."""
    if not enabled:
        yield None
        return
    tap = LinkTap(link)
    try:
        yield tap
    finally:
        tap.close()
