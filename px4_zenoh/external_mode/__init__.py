"""PX4 external modes over PX4's own zenoh module, from Python, without ROS (docs/px4-zenoh.md).

- ``mode.py``: ``ExternalMode``: register a named mode, answer PX4's arming checks, know when it is active,
  send setpoints only then, report completion, unregister on close.
- ``messages.py``: the uORB messages, built as PX4's commander reads them.
- ``bridge.py``: which topics this PX4's zenoh bridge misroutes, and the refusal to send them.
"""
from __future__ import annotations

from .bridge import BridgeBugError, BridgePolicy
from .messages import INTERNAL_MODES, event_text, internal_mode
from .mode import Check, ExternalMode, ModeStats, Registration, RegistrationError

__all__ = ["INTERNAL_MODES", "BridgeBugError", "BridgePolicy", "Check", "ExternalMode", "ModeStats", "Registration",
           "RegistrationError", "event_text", "internal_mode"]
