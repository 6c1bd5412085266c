"""``gcs --mavlink-out udpout:127.0.0.1:14550``: a drone's tunnelled MAVLink to a local QGroundControl.

Datagrams from ``<id>/mavlink/down`` (see companion/mavlink_tunnel.py) are sent as they
are to QGC's UDP port; what QGC sends back to our socket goes up on ``<id>/mavlink/up``,
where the companion's policy decides (read-only by default). QGC sees the vehicle as
if PX4 were on this machine, beside the dashboard.
"""
from __future__ import annotations

import logging
import select
import socket
import threading
from dataclasses import dataclass
from typing import Any

from drone_contract.tunnel import MAX_DATAGRAM, TUNNEL_DOWN, TUNNEL_QOS, TUNNEL_UP, MavlinkPacket

log = logging.getLogger("gcs.mavlink_out")


@dataclass
class OutCounters:
    down: int = 0        # datagrams sent to QGC
    up: int = 0          # datagrams from QGC published
    send_errors: int = 0


def parse_udpout(spec: str) -> tuple[str, int]:
    kind, _, rest = spec.partition(":")
    host, _, port = rest.rpartition(":")
    if kind != "udpout" or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--mavlink-out takes udpout:HOST:PORT (e.g. udpout:127.0.0.1:14550), got {spec!r}")
    return host, int(port)


class MavlinkOut:
    def __init__(self, node: Any, drone_ns: str, spec: str) -> None:
        self.target = parse_udpout(spec)
        self.counters = OutCounters()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1" if self.target[0].startswith("127.") else "0.0.0.0", 0))
        ns = "/" + drone_ns.strip("/")
        self._up = node.create_publisher(MavlinkPacket, f"{ns}/{TUNNEL_UP}", TUNNEL_QOS)
        self._sub = node.create_subscription(MavlinkPacket, f"{ns}/{TUNNEL_DOWN}", self._on_down, TUNNEL_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read_qgc, name="mavlink-out", daemon=True)
        self._thread.start()
        self._error_logged = False

    def _on_down(self, pkt: MavlinkPacket) -> None:
        try:
            self._sock.sendto(bytes(pkt.data), self.target)
            self.counters.down += 1
        except OSError as exc:    # QGC not started yet: ICMP refusals are normal, counted, logged once
            self.counters.send_errors += 1
            if not self._error_logged:
                self._error_logged = True
                log.info("MAVLink to %s:%d not delivered yet (%s)", *self.target, exc)

    def _read_qgc(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._sock], [], [], 0.2)
                if not ready:
                    continue
                data, _addr = self._sock.recvfrom(MAX_DATAGRAM)
            except OSError:
                if self._stop.is_set():
                    return
                continue
            self._up.publish(MavlinkPacket(data))
            self.counters.up += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()

