"""Limits both sides of the GCS <-> drone contract rely on.

The companion enforces these (its parameters start from them, companion/params.py bounds them);
the GCS plans within them, so a mission never asks for what the drone would refuse.
"""
from __future__ import annotations

# The GCS offers this deadline on setpoints: PX4 leaves OFFBOARD below 2 Hz, so a setpoint
# stream that promises less is no use. A companion may request any deadline >= this one.
SETPOINT_DEADLINE_S = 0.5
# The companion's own setpoint deadline before its failsafe HOLD (its -p setpoint_deadline).
COMPANION_DEADLINE_S = 1.0
MAX_OFFSET_M = 10.0       # how far a position target may lie from the vehicle (plus 1 s of its speed)
MAX_SPEED_MS = 10.0       # the fastest velocity target accepted, m/s
CONTROL_LEASE_S = 5.0     # a GCS in control heard from neither by token nor setpoint loses control after this
TAKEOFF_ALT_M = (0.5, 120.0)   # the takeoff altitudes a command may ask for, m
DEFAULT_TAKEOFF_ALT_M = 5.0
# What the GCS plans within, with a margin under the companion's limits above.
GCS_MAX_LEAD_M = MAX_OFFSET_M / 2          # how far ahead of the drone a target may lie
GCS_MAX_TARGET_SPEED_MS = MAX_SPEED_MS / 2  # how fast a formation target may move
