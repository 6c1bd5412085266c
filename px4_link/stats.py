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
    setpoints_clamped: int = 0     # velocity targets cut by the geofence (episodes)
    setpoints_expired: int = 0     # velocity targets not refreshed in time: zero velocity sent
    commands_sent: int = 0
    command_retries: int = 0
    reconnects: int = 0
    disconnects: int = 0
    callback_errors: int = 0
    spoofed_frames: int = 0        # our vehicle's ids from an address that is not the vehicle
    nonfinite_telemetry: int = 0   # samples with NaN/inf dropped before listeners
    duplicate_acks: int = 0        # a second ACK for an already answered command
    unsolicited_acks: int = 0      # ACKs for nothing we wait for, or addressed to others
    bad_signatures: int = 0        # unsigned / wrongly signed frames when signing is on
    vehicle_commands_ignored: int = 0  # COMMAND_LONGs PX4 sends to other components
    reboots: int = 0               # boot clock went backwards
    interval_rerequests: int = 0   # message intervals asked again after reconnect/reboot
    link_losses: int = 0           # serial: the device vanished (unplugged, PX4 rebooted on USB)
    baud_mismatches: int = 0       # serial: episodes of bytes without one MAVLink frame (wrong rate)
    bytes_dropped_tx: int = 0      # serial: bytes the driver could not take (never waited for)
