"""ROS 2-style node parameters (filled in by the services/parameters work)."""
from __future__ import annotations

from typing import Any


class ParametersMixin:
    def _init_parameters(self, overrides: dict[str, Any]) -> None:
        self._parameter_overrides = dict(overrides)
