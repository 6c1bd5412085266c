"""Px4ZenohLink: the link to PX4 over PX4's own Zenoh module, with Px4Link's face (``VehicleLink``).

It opens the PX4-side session (``session.py``: an embedded router PX4 joins, or a client of a
router), loads the px4_msgs types (bundled, or a PX4 tree's with ``msg_dir``), and hangs px4_link's
``Action`` and this package's offboard, parameter and telemetry plugins on a ``ZenohCore``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import zenoh

from px4_link.action import Action
from px4_link.offboard import VELOCITY_TIMEOUT_S
from px4_link.plugin import EventCallback
from px4_link.targets import Geofence
from px4_link.vehicle import VehicleLinkBase

from . import topics as tp
from .core import ZenohCore
from .offboard import ZenohOffboard
from .services import ZenohParam, ZenohTelemetry
from .session import Px4Endpoint, open_px4_session
from .uorb import load_types

_DEFAULT_GEOFENCE = Geofence()


class Px4ZenohLink(VehicleLinkBase[ZenohCore]):
    """Use as a context manager, as Px4Link::

        with Px4ZenohLink(Px4Endpoint("router", "tcp/127.0.0.1:7447")) as link:
            link.wait_connected(10)

    Events: connected, disconnected, rebooted, mode_changed, armed_changed, landed_changed,
    offboard_lost, setpoint_rejected / _clamped / _expired (px4_link's offboard), hash_mismatch."""

    def __init__(self, where: Px4Endpoint | zenoh.Session, *, msg_dir: Path | None = None, domain: int = 0,
                 heartbeat_timeout: float = 3.0, setpoint_rate_hz: float = 20.0,
                 geofence: Geofence | None = _DEFAULT_GEOFENCE, max_speed: float | None = 10.0,
                 velocity_timeout_s: float = VELOCITY_TIMEOUT_S, source_system: int = 245,
                 source_component: int = 191, target_system: int = 1, on_event: EventCallback | None = None,
                 command_timeout: float = 1.0, command_retries: int = 3) -> None:
        if setpoint_rate_hz < 10.0:
            raise ValueError("setpoint_rate_hz must be >= 10")   # COM_OF_LOSS_T 1 s; margin as Px4Link
        self.where = where if isinstance(where, Px4Endpoint) else None
        self._own_session = isinstance(where, Px4Endpoint)
        types = load_types(msg_dir, sorted({t.type_short for t in tp.USED}))
        session = open_px4_session(where) if isinstance(where, Px4Endpoint) else where
        self._core = ZenohCore(session, types, domain=domain, heartbeat_timeout=heartbeat_timeout,
                               tick_hz=setpoint_rate_hz, source_system=source_system,
                               source_component=source_component, target_system=target_system,
                               command_timeout=command_timeout, command_retries=command_retries)
        if on_event is not None:
            self._core.add_event_listener(on_event)
        self.action = Action(self._core)
        self.offboard = ZenohOffboard(self._core, geofence, max_speed, velocity_timeout_s)
        self.param = ZenohParam(self._core)
        self.telemetry = ZenohTelemetry(self._core)

    # ----------------------------------------------------------------- lifecycle
    def stop(self) -> None:
        """Stop the core's threads, undeclare its entities and close the session if it opened it."""
        super().stop()
        if self._own_session:
            self._own_session = False
            self._core.session.close()

    @property
    def core(self) -> ZenohCore:
        return self._core

    @property
    def connection(self) -> str:
        return str(self.where) if self.where is not None else "zenoh (shared session)"

    # ----------------------------------------------------------------- state
    @property
    def stats(self) -> dict[str, int]:
        return self._core.stats()

    def hash_mismatches(self) -> list[tp.HashMismatch]:
        return self._core.keys.mismatches()

    def backend_summary(self) -> dict[str, Any]:
        """What the companion's summary shows of this backend: the keys learnt, the mismatches, counters."""
        return {"backend": "zenoh", "connection": self.connection,
                "keys_learnt": sorted(self._core.keys.known()),
                "hash_mismatches": [str(m) for m in self.hash_mismatches()], "stats": self.stats,
                **self._mode_summary()}

    def _mode_summary(self) -> dict[str, Any]:
        """The external mode flown instead of OFFBOARD (``external_mode.offboard``), when there is one."""
        summary = getattr(self.offboard, "summary", None)
        return {"external_mode": summary()} if callable(summary) else {}
