"""PX4 external modes over PX4's own zenoh module, from Python, without ROS (docs/px4-zenoh.md).

- ``mode.py``: ``ExternalMode``: register a named mode, answer PX4's arming checks, know when it is active,
  send setpoints only then, report completion, unregister on close.
- ``messages.py``: the uORB messages, built as PX4's commander reads them.
- ``bridge.py``: which topics this PX4's zenoh bridge misroutes, and the refusal to send them.
- ``rtl.py``: ``ReturnHome``: a companion RTL registered as the replacement of PX4's.
- ``executor.py``: ``ModeExecutor``: arm, take off, the owned mode, RTL, while PX4 keeps it in charge (a fixed
  bridge only).
"""
from __future__ import annotations

from .bridge import BridgeBugError, BridgePolicy
from .executor import ModeExecutor
from .messages import INTERNAL_MODES, event_text, internal_mode
from .mode import Check, ExternalMode, ModeStats, Registration, RegistrationError
from .rtl import ReturnHome

__all__ = ["INTERNAL_MODES", "BridgeBugError", "BridgePolicy", "Check", "ExternalMode", "ModeExecutor", "ModeStats",
           "Registration", "RegistrationError", "ReturnHome", "event_text", "internal_mode"]
