"""QGC alongside: the simulator's MAVLink bytes reach a local UDP port through Zenoh, and QGC's
traffic goes back only under the companion's policy.

Real parts: px4_link.sim.Simulator over UDP, the tee, two Nodes on loopback sockets
(companion side and GCS side), a UDP socket standing in for QGroundControl.
"""
from __future__ import annotations

import socket
import threading
import time

import pytest
from conftest import linked_nodes, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink_tunnel import MavlinkPolicy, MavlinkTunnel, UdpTee, free_udp_port
from drone_contract.tunnel import TUNNEL_QOS, TUNNEL_UP, MavlinkPacket
from gcs.mavlink_out import MavlinkOut, parse_udpout
from px4_link.sim import Simulator


class Qgc:
    """A UDP socket that collects MAVLink messages like QGC listening on its port."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.mav.robust_parsing = True
        self.msgs: list = []
        self.peer: tuple[str, int] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, OSError):
                continue
            self.peer = addr
            self.msgs.extend(m for m in (parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA")

    def of(self, name: str) -> list:
        return [m for m in list(self.msgs) if m.get_type() == name]

    def send(self, msg) -> None:
        assert self.peer is not None
        self.sock.sendto(msg.pack(self.mav), self.peer)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def test_policy_lets_reads_up_and_refuses_control():
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    policy = MavlinkPolicy()
    read = mav.param_request_read_encode(1, 1, b"MPC_XY_VEL_MAX", -1).pack(mav)
    info = mav.command_long_encode(1, 1, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0).pack(mav)
    arm = mav.command_long_encode(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
    sp = mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0, 1.0, 0, -2, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav)
    assert policy.refused(policy.frames(read)) == [] and policy.refused(policy.frames(info)) == []
    assert [m.get_type() for m in policy.refused(policy.frames(arm))] == ["COMMAND_LONG"]
    assert [m.get_type() for m in policy.refused(policy.frames(read + sp))] == ["SET_POSITION_TARGET_LOCAL_NED"]
    assert policy.frames(b"\x00garbage\xff" * 5) == []
    assert MavlinkPolicy(allow_control=True).refused(policy.frames(arm)) == []
    with pytest.raises(ValueError):
        parse_udpout("udp:127.0.0.1:14550")


def test_tunnel_delivers_heartbeats_to_qgc_and_refuses_arming(ns):
    link = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # stands in for the companion's Px4Link
    link.bind(("127.0.0.1", 0))
    link.settimeout(2.0)
    tee = UdpTee(("127.0.0.1", free_udp_port()), link.getsockname()[1], lambda d: None).start()
    qgc = Qgc()
    with linked_nodes(ns) as (companion_node, gcs_node), Simulator(1, port=0, target_port=tee.port) as sim:
        tunnel = MavlinkTunnel(companion_node, tee)
        out = MavlinkOut(gcs_node, ns, f"udpout:127.0.0.1:{qgc.port}")
        spinners = [threading.Thread(target=n.spin, kwargs={"timeout": 30}, daemon=True)
                    for n in (companion_node, gcs_node)]
        for s in spinners:
            s.start()
        try:
            # The companion's own link still gets PX4's bytes through the tee.
            assert link.recvfrom(65535)[0]
            assert wait_for(lambda: any(m.get_srcSystem() == 1 for m in qgc.of("HEARTBEAT")), 15.0), \
                f"QGC got {len(qgc.msgs)} messages; tunnel {tunnel.counters}, out {out.counters}"
            assert tunnel.counters.down > 0 and out.counters.down > 0
            # A read goes up and is answered by the vehicle.
            qgc.send(qgc.mav.param_request_read_encode(1, 1, b"MAV_SYS_ID", -1))
            assert wait_for(lambda: any(m.param_id == "MAV_SYS_ID" for m in qgc.of("PARAM_VALUE")), 10.0), \
                tunnel.counters
            # Arming from QGC is refused, counted, and answered DENIED; the vehicle stays disarmed.
            qgc.send(qgc.mav.command_long_encode(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            assert wait_for(lambda: any(a.command == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM and
                                        a.result == mavlink2.MAV_RESULT_DENIED for a in qgc.of("COMMAND_ACK")), 10.0)
            assert tunnel.counters.refused_by_message["COMMAND_LONG"] == 1
            assert any("refused" in m.text for m in qgc.of("STATUSTEXT"))
            time.sleep(0.5)
            assert not sim.armed
            assert tunnel.counters.up_forwarded >= 1
        finally:
            companion_node.shutdown()
            gcs_node.shutdown()
            for s in spinners:
                s.join(timeout=5)
            out.close()
            tunnel.close()
            qgc.close()
            link.close()


class FakePx4:
    """A UDP socket where PX4 would be: says hello to the tee (so the tee knows where PX4 is) and
    collects every datagram the tee sends it."""

    def __init__(self, tee: UdpTee) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.sock.sendto(mav.heartbeat_encode(2, 12, 0, 0, 3).pack(mav), ("127.0.0.1", tee.port))
        assert wait_for(lambda: tee.px4_addr == self.sock.getsockname(), 5.0)
        self.got: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.got.append(self.sock.recvfrom(65535)[0])
            except (TimeoutError, OSError):
                continue

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def _frames() -> dict[str, bytes]:
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    mav.seq = 41
    read = mav.param_request_read_encode(1, 1, b"MPC_XY_VEL_MAX", -1).pack(mav)
    info = mav.command_long_encode(1, 1, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0).pack(mav)
    arm = mav.command_long_encode(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
    arm2 = mav.command_long_encode(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)
    bad_crc = bytearray(arm2)
    bad_crc[-1] ^= 0xFF
    return {"read": read, "info": info, "arm": arm, "arm_bad_crc": bytes(bad_crc)}


def test_policy_judges_frame_by_frame_and_counts_what_is_no_frame():
    f = _frames()
    policy = MavlinkPolicy()
    j = policy.judge(b"\x00garbage\xff" + f["read"] + f["arm_bad_crc"] + f["info"] + f["arm"][:9])
    assert [m.get_type() for m in j.accepted] == ["PARAM_REQUEST_READ", "COMMAND_LONG"]
    assert j.refused == []
    assert j.bad_data == 2 and j.partial          # the garbage, the frame failing its CRC; the cut frame
    assert j.dropped_bytes == len(b"\x00garbage\xff") + len(f["arm_bad_crc"]) + 9
    # Re-encoded from the decoded fields, each frame is the very frame QGC sent (seq, ids, CRC).
    assert [policy.encode(m) for m in j.accepted] == [f["read"], f["info"]]
    # A MAVLink 1 frame stays MAVLink 1.
    mav1 = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    v1 = mav1.heartbeat_encode(6, 8, 0, 0, 0).pack(mav1, force_mavlink1=True)
    assert policy.encode(policy.judge(v1).accepted[0]) == v1
    # The parser keeps nothing between datagrams: a frame cut across two is two partial drops.
    first, second = policy.judge(f["read"][:8]), policy.judge(f["read"][8:])
    assert first.accepted == second.accepted == [] and first.partial


def test_tunnel_forwards_only_the_frames_it_accepted(ns):
    """Garbage, a frame failing its CRC, a truncated frame and a forbidden command around allowed
    frames: only the allowed frames' bytes reach PX4, and the counters say what was dropped."""
    f = _frames()
    link = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # stands in for the companion's Px4Link
    link.bind(("127.0.0.1", 0))
    tee = UdpTee(("127.0.0.1", free_udp_port()), link.getsockname()[1], lambda d: None).start()
    px4 = FakePx4(tee)
    with linked_nodes(ns) as (gcs_node, companion_node):
        tunnel = MavlinkTunnel(companion_node, tee)
        up = gcs_node.create_publisher(MavlinkPacket, TUNNEL_UP, TUNNEL_QOS)
        spinner = threading.Thread(target=companion_node.spin, kwargs={"timeout": 20}, daemon=True)
        spinner.start()
        try:
            assert wait_for(lambda: up.get_subscription_count() > 0, 5.0)
            time.sleep(0.5)
            garbage = b"\x00\x01not mavlink\xfe"   # ends in a v1 marker: the parser waits for more
            up.publish(MavlinkPacket(b"\x55garbage" + f["read"] + f["arm_bad_crc"] + f["read"][:12]))
            assert wait_for(lambda: len(px4.got) >= 1, 5.0), tunnel.counters
            assert px4.got == [f["read"]]
            c = tunnel.counters
            assert (c.up_forwarded, c.up_frames_forwarded, c.up_bad_data, c.up_partial) == (1, 1, 2, 1), c
            assert c.up_dropped_bytes == len(b"\x55garbage") + len(f["arm_bad_crc"]) + 12, c
            # An allowed frame followed by a forbidden command in one datagram: only the allowed one.
            up.publish(MavlinkPacket(f["info"] + f["arm"]))
            assert wait_for(lambda: len(px4.got) >= 2, 5.0), tunnel.counters
            assert px4.got[1] == f["info"]
            assert c.refused_by_message["COMMAND_LONG"] == 1 and c.up_refused == 1
            # Bytes that are no frame at all go nowhere.
            up.publish(MavlinkPacket(garbage))
            assert wait_for(lambda: c.up_malformed == 1, 5.0), c
            time.sleep(0.5)
            assert len(px4.got) == 2, px4.got
            assert not any(b"garbage" in d or b"mavlink" in d for d in px4.got)
        finally:
            companion_node.shutdown()
            spinner.join(timeout=5)
            tunnel.close()
            px4.close()
            link.close()


def test_tee_relays_to_px4_only_from_the_link_and_only_px4_to_the_link():
    link = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    link.bind(("127.0.0.1", 0))
    link.settimeout(0.5)
    tee = UdpTee(("127.0.0.1", free_udp_port()), link.getsockname()[1], lambda d: None).start()
    px4 = FakePx4(tee)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind(("127.0.0.1", 0))
    try:
        assert link.recvfrom(65535)[0]                      # PX4's hello reached the link
        link_side = ("127.0.0.1", tee._link_side.getsockname()[1])
        link.sendto(b"from the link", link_side)
        assert wait_for(lambda: b"from the link" in px4.got, 5.0)
        stranger.sendto(b"from a stranger", link_side)      # a local process on the link side
        stranger.sendto(b"posing as px4", ("127.0.0.1", tee.port))
        assert wait_for(lambda: tee.foreign == 2, 5.0), tee.foreign
        time.sleep(0.3)
        assert b"from a stranger" not in px4.got
        assert tee.px4_addr == px4.sock.getsockname()
        with pytest.raises(TimeoutError):
            link.recvfrom(65535)                             # the impostor's datagram never reached the link
    finally:
        tee.close()
        px4.close()
        stranger.close()
        link.close()
