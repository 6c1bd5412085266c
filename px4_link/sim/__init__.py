"""A PX4-faithful MAVLink vehicle simulator (``python -m px4_link.sim``)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..lazy import lazy_exports

if TYPE_CHECKING:   # loaded on first use (px4_link/lazy.py: a Ctrl-C at start-up)
    from .base import DEFAULT_HOME
    from .commander import FAILSAFE_MODES, FailsafeEvent, ModeChange, ReceivedSetpoint
    from .params import PX4_PARAMS, ParamStore
    from .protocol import DEFAULT_RATES_HZ
    from .simulator import Simulator

__all__ = ["Simulator", "ModeChange", "FailsafeEvent", "FAILSAFE_MODES", "ReceivedSetpoint", "ParamStore", "PX4_PARAMS",
           "DEFAULT_RATES_HZ", "DEFAULT_HOME"]

__getattr__ = lazy_exports(__name__, {
    ".base": ("DEFAULT_HOME",),
    ".commander": ("FAILSAFE_MODES", "FailsafeEvent", "ModeChange", "ReceivedSetpoint"),
    ".params": ("PX4_PARAMS", "ParamStore"),
    ".protocol": ("DEFAULT_RATES_HZ",),
    ".simulator": ("Simulator",),
})
