"""Link counters, copied out as an immutable snapshot so readers never see a torn update."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class LinkStats:
    bytes_received: int = 0
    messages_received: int = 0
    garbage_bytes: int = 0         # bytes that were not part of a valid MAVLink frame
    bad_frames: int = 0            # garbage runs and broken frames
    crc_errors: int = 0
    unknown_messages: int = 0      # valid frames of message ids outside the dialect
    other_system_messages: int = 0 # from a system id other than our vehicle's
    bytes_sent: int = 0
    messages_sent: int = 0
    heartbeats_received: int = 0
    heartbeats_sent: int = 0
    setpoints_sent: int = 0
    setpoints_rejected: int = 0
    commands_sent: int = 0
    command_retries: int = 0
    reconnects: int = 0
    disconnects: int = 0
    callback_errors: int = 0
