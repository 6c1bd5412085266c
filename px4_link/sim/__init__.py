"""A PX4-faithful MAVLink vehicle simulator (``python -m px4_link.sim``)."""
from .base import DEFAULT_HOME
from .commander import FAILSAFE_MODES, FailsafeEvent, ModeChange, ReceivedSetpoint
from .params import PX4_PARAMS, ParamStore
from .protocol import DEFAULT_RATES_HZ
from .simulator import Simulator

__all__ = ["Simulator", "ModeChange", "FailsafeEvent", "FAILSAFE_MODES", "ReceivedSetpoint", "ParamStore", "PX4_PARAMS",
           "DEFAULT_RATES_HZ", "DEFAULT_HOME"]
