"""QGC through the companion's MAVLink tunnel with PX4 on a serial port: the tunnel taps px4_link
(``LinkTap``) instead of a UDP tee, since the serial port has one holder.

Real parts: the built-in simulator behind a pseudo-terminal (tests/pty_px4.py: the link opens a real
tty through pyserial), a real companion process with ``--mavlink-tunnel``, and a test-side Zenoh node
that plays ``gcs --mavlink-out``: it reads ``<id>/mavlink/down`` and publishes QGC's frames on
``<id>/mavlink/up``. The tap and the link's raw-frame API are also tested on their own.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest
from conftest import python_proc, stop_process, wait_for
from pty_px4 import PtyWire
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink_tunnel import LinkTap, datagrams
from drone_contract.tunnel import MAX_DATAGRAM, TUNNEL_DOWN, TUNNEL_QOS, TUNNEL_UP, MavlinkPacket
from px4_link import Px4Link
from px4_link.sim import Simulator
from zenoh_robot import Node

WAIT = 10.0


# The companion and the test's node in a Zenoh domain of their own: another test's companion would hear them.
pytestmark = pytest.mark.usefixtures("own_domain")


def _qgc() -> Any:
    return mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)


class Frames:
    """Collects MAVLink messages from datagrams, each parsed on its own (as QGC does with UDP), and
    counts what a datagram held that was no whole frame: the tunnel must publish whole frames only."""

    def __init__(self) -> None:
        self.msgs: list[Any] = []
        self.datagrams = 0
        self.most_frames = 0     # the most frames one datagram carried
        self.broken = 0          # bad data or a partial frame in a datagram
        self._lock = threading.Lock()

    def __call__(self, data: bytes) -> None:
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        msgs = parser.parse_buffer(data) or []
        with self._lock:
            self.datagrams += 1
            good = [m for m in msgs if m.get_type() != "BAD_DATA"]
            self.broken += len(msgs) - len(good) + (1 if parser.buf_len() else 0)
            self.most_frames = max(self.most_frames, len(good))
            self.msgs.extend(good)

    def of(self, name: str) -> list[Any]:
        with self._lock:
            return [m for m in self.msgs if m.get_type() == name]


def _until(send: Callable[[], None], seen: Callable[[], bool], timeout: float = WAIT) -> bool:
    """Send (best effort, as the tunnel is), again every second, until ``seen``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        send()
        if wait_for(seen, min(1.0, max(0.0, deadline - time.monotonic()))):
            return True
    return seen()


def test_qgc_through_a_companion_on_a_serial_port(ns: str, wired: tuple[Simulator, PtyWire]) -> None:
    sim, wire = wired
    down = Frames()
    proc = python_proc("-m", "companion", "--id", ns, "--px4", f"{wire.path}:921600", "--mavlink-tunnel",
                       "--camera", "none")
    try:
        with Node("qgc_side", namespace=ns) as node:
            node.create_subscription(MavlinkPacket, TUNNEL_DOWN, lambda p: down(bytes(p.data)), TUNNEL_QOS)
            up = node.create_publisher(MavlinkPacket, TUNNEL_UP, TUNNEL_QOS)
            threading.Thread(target=node.spin, kwargs={"timeout": 60}, daemon=True).start()
            assert wait_for(lambda: any(m.get_srcSystem() == 1 for m in down.of("HEARTBEAT")), 30), \
                f"no heartbeat of system 1 down the tunnel ({down.datagrams} datagrams)"
            assert wait_for(lambda: up.get_subscription_count() > 0, WAIT)
            qgc = _qgc()

            # A read goes up the serial line and PX4's answer comes back down.
            read = qgc.param_request_read_encode(1, 1, b"COM_OF_LOSS_T", -1).pack(qgc)
            assert _until(lambda: up.publish(MavlinkPacket(read)),
                          lambda: any(m.param_id == "COM_OF_LOSS_T" for m in down.of("PARAM_VALUE"))), \
                "no PARAM_VALUE down the tunnel"
            assert sim.bad_frames_received == 0, "a frame from QGC reached PX4 broken"

            # Arming from QGC is refused by the companion: DENIED comes back, PX4 never hears it.
            arm = qgc.command_long_encode(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            frame = arm.pack(qgc)
            assert _until(lambda: up.publish(MavlinkPacket(frame)),
                          lambda: any(a.command == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
                                      and a.result == mavlink2.MAV_RESULT_DENIED and a.target_system == 255
                                      for a in down.of("COMMAND_ACK")))
            assert any("refused" in m.text for m in down.of("STATUSTEXT"))
            time.sleep(0.5)
            assert not sim.armed

            # Whole frames only, several to a datagram (grouped, not one publish per frame).
            assert down.broken == 0
            assert down.most_frames > 1, down.most_frames
        assert proc.poll() is None, "the companion stopped"
    finally:
        out = stop_process(proc, 10.0)
    assert "Traceback" not in out, out


def test_raw_frames_through_the_link_on_a_pty(wired: tuple[Simulator, PtyWire]) -> None:
    """The link's raw API: every accepted frame's bytes out, a foreign frame in, whole, between the
    link's own; on a busy line a raw frame is refused at once rather than queued."""
    sim, wire = wired
    got: list[bytes] = []
    with Px4Link(f"{wire.path}:57600") as link:
        link.add_frame_listener(got.append)      # added while the link runs
        assert link.wait_connected(WAIT)
        assert wait_for(lambda: len(got) > 5, WAIT)
        parser = mavlink2.MAVLink(None)
        assert all(len(parser.parse_buffer(f) or []) == 1 for f in got[:20])   # one whole frame each

        qgc = _qgc()
        read = qgc.param_request_read_encode(1, 1, b"COM_OF_LOSS_T", -1).pack(qgc)
        assert link.send_raw(read)
        assert wait_for(lambda: any(b"COM_OF_LOSS_T" in f for f in got), WAIT)
        # At 57600 baud a burst of raw frames fills the line's budget (30 ms, 172 bytes): the rest is
        # refused, not queued, and the link's own traffic carries on.
        burst = [link.send_raw(read) for _ in range(100)]
        assert burst[0] and not all(burst), burst
        assert wait_for(lambda: link.send_raw(read), 1.0)   # the line drained: room again
        beats = link.stats.heartbeats_sent
        assert link.wait_until(lambda: link.stats.heartbeats_sent > beats, WAIT)
        assert link.stats.bytes_dropped_tx == 0
    assert sim.bad_frames_received == 0


class FakeLink:
    def __init__(self) -> None:
        self.listeners: list[Callable[[bytes], None]] = []
        self.sent: list[bytes] = []
        self.room = 2

    def add_frame_listener(self, listener: Callable[[bytes], None]) -> None:
        self.listeners.append(listener)

    def send_raw(self, frame: bytes) -> bool:
        if self.room <= 0:
            return False
        self.room -= 1
        self.sent.append(frame)
        return True


@pytest.mark.fast
def test_the_tap_groups_frames_bounds_its_queue_and_counts_refused_frames() -> None:
    link = FakeLink()
    published: list[bytes] = []
    tap = LinkTap(link, published.append)
    try:
        (feed,) = link.listeners
        qgc = _qgc()
        frames = [qgc.heartbeat_encode(6, 8, 0, 0, 0).pack(qgc) for _ in range(5)]
        for f in frames:
            feed(f)
        assert wait_for(lambda: tap.frames == 5, 2.0)
        assert b"".join(published) == b"".join(frames) and len(published) < 5   # grouped, in order
        # Up: what the line takes goes, the rest is dropped and said.
        assert tap.inject_frames(frames[:3]) == 2 and link.sent == frames[:2]
    finally:
        tap.close()
    # Closed: nothing queued any more.
    feed(frames[0])
    assert tap.frames == 5
    # Never a datagram over the limit, never a frame split.
    groups = list(datagrams([b"a" * 40_000, b"b" * 30_000, b"c" * 20_000, b"d" * 5_000]))
    assert [sum(map(len, g)) for g in groups] == [40_000, 55_000]
    assert all(sum(map(len, g)) <= MAX_DATAGRAM for g in groups)


@pytest.mark.fast
def test_the_tap_drops_and_counts_when_its_publisher_falls_behind() -> None:
    link = FakeLink()
    release = threading.Event()
    tap = LinkTap(link, lambda d: release.wait(5.0))   # a publisher stuck in Zenoh
    drops: list[int] = []
    tap.on_drop = drops.append
    try:
        (feed,) = link.listeners
        feed(b"x" * 100)
        assert wait_for(lambda: tap.frames == 1, 2.0)   # taken, its publish hangs
        for _ in range(3):
            feed(b"y" * 30_000)      # the third is over MAX_PENDING
        assert tap.dropped == 1 and drops == [1]
        release.set()
        assert wait_for(lambda: tap.frames == 3, 2.0)
    finally:
        release.set()
        tap.close()
