"""``link.param``: PX4 parameters over PARAM_REQUEST_READ / PARAM_SET."""
from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

from .commands import CommandError, CommandTimeout, NotConnected
from .plugin import Core
from .wire import float_bits_to_int, int_to_float_bits, mavlink2


class ParamError(CommandError):
    """The vehicle echoed a different value than the one set."""


class Param:
    def __init__(self, core: Core) -> None:
        self._core = core
        self._waiters: dict[str, list[list[float | int]]] = {}
        self._lock = threading.Lock()
        core.add_message_handler("PARAM_VALUE", self._on_param_value)

    def get(self, name: str, timeout: float = 1.0, retries: int = 3) -> float | int:
        """INT32 params are decoded from PX4's bytewise encoding."""
        core = self._core

        def request() -> None:
            sysid, compid = core.vehicle_ids()
            core.send_message(core.encoder().param_request_read_encode(sysid, compid, name.encode(), -1))
        return self._exchange(name, request, timeout, retries)

    def set(self, name: str, value: float | int, timeout: float = 1.0, retries: int = 3) -> float | int:
        """Ints go as MAV_PARAM_TYPE_INT32 (bytewise), floats as REAL32; returns the echo."""
        core = self._core
        if isinstance(value, (bool, int)):
            ptype, wire = mavlink2.MAV_PARAM_TYPE_INT32, int_to_float_bits(int(value))
        else:
            ptype, wire = mavlink2.MAV_PARAM_TYPE_REAL32, float(value)

        def request() -> None:
            sysid, compid = core.vehicle_ids()
            core.send_message(core.encoder().param_set_encode(sysid, compid, name.encode(), wire, ptype))
        got = self._exchange(name, request, timeout, retries)
        same = got == int(value) if ptype == mavlink2.MAV_PARAM_TYPE_INT32 else \
            math.isclose(got, value, rel_tol=1e-6)
        if not same:
            raise ParamError(0, None, f"PARAM_SET {name}={value}: vehicle reports {got}")
        return got

    def _on_param_value(self, m: Any) -> None:
        """PARAM_VALUE from the vehicle (receive thread)."""
        name = m.param_id if isinstance(m.param_id, str) else bytes(m.param_id).decode(errors="replace")
        name = name.rstrip("\x00")
        if m.param_type in (mavlink2.MAV_PARAM_TYPE_REAL32, mavlink2.MAV_PARAM_TYPE_REAL64):
            value: float | int = float(m.param_value)
        else:  # PX4 sends integers bytewise inside the float field
            value = float_bits_to_int(m.param_value)
        with self._lock:
            for slot in self._waiters.get(name, []):
                if not slot:
                    slot.append(value)
        self._core.notify()

    def _exchange(self, name: str, request: Callable[[], None], timeout: float, retries: int) -> float | int:
        if not self._core.connected:
            raise NotConnected(0, None, f"param {name}: no vehicle connected")
        slot: list[float | int] = []
        with self._lock:
            self._waiters.setdefault(name, []).append(slot)
        try:
            for _ in range(retries + 1):
                request()
                if self._core.wait_until(lambda: bool(slot), timeout):
                    return slot[0]
            raise CommandTimeout(0, None, f"param {name}: no PARAM_VALUE after {retries + 1} attempts")
        finally:
            with self._lock:
                waiters = self._waiters.get(name, [])
                if slot in waiters:
                    waiters.remove(slot)
                if not waiters:
                    self._waiters.pop(name, None)
