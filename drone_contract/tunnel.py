"""The MAVLink tunnel's packet and streams: PX4's MAVLink datagrams over the drone's Zenoh session.

The companion publishes what PX4 sends on ``<id>/mavlink/down`` and forwards what arrives on
``<id>/mavlink/up`` under its policy (companion/mavlink_tunnel.py); ``gcs --mavlink-out`` is the
other end (gcs/mavlink_out.py).
"""
from __future__ import annotations

from zenoh_robot.message import Message, message
from zenoh_robot.qos import QoSProfile, ReliabilityPolicy

MAX_DATAGRAM = 65535
# Bursty telemetry, best effort (MAVLink has its own retries for what matters), a deep queue.
TUNNEL_QOS = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=200)
TUNNEL_DOWN = "mavlink/down"   # drone -> GCS: what PX4 sent
TUNNEL_UP = "mavlink/up"       # GCS -> drone: what QGC sent


@message(name="zenoh_robot/MavlinkPacket")
class MavlinkPacket(Message):
    """One UDP datagram of MAVLink, as PX4 or QGC sent it (one or more frames)."""
    data: bytes = b""
