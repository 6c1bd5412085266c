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
