"""The GCS's settings: one dataclass, what the CLI validated (gcs/cli.py) and the app runs with; the
node shows them as read-only parameters (``GcsConfig.parameters``)."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drone_contract.streams import StreamProfile, stream_profile


def default_client_id() -> str:
    import getpass
    import socket
    raw = f"{getpass.getuser()}@{socket.gethostname()}"
    return re.sub(r"[^A-Za-z0-9_.@:+-]", "_", raw)[:64]


@dataclass
class GcsConfig:
    drones: list[str] = field(default_factory=list)     # empty: discover
    pattern: str = "thesis"
    rate_hz: float = 10.0
    altitude: float = 5.0
    size: float = 10.0
    speed: float = 2.0
    profile: StreamProfile = field(default_factory=lambda: stream_profile("resilient"))
    save_image: Path | None = None   # write the latest frame here every `save_every` s
    save_every: float = 5.0
    client_id: str = field(default_factory=default_client_id)
    take_control: bool = False       # take control from another GCS at start (explicit takeover)
    auto_fly: bool = True            # fly the pattern as soon as a drone's session is active (no --mission)
    formation: str = "none"          # none (each drone from its own anchor), line, grid: see gcs/formation.py
    spacing: float = 5.0             # m between formation slots
    patterns: dict[str, str] = field(default_factory=dict)   # drone id -> its own pattern
    # Downlink rates asked of each drone when it joins (gcs/downlink.py); None: the companion's own.
    sensor_rate_hz: float | None = None
    camera_rate_hz: float | None = None
    # A drone whose sensor this GCS cannot keep up with is asked for less (gcs/decimation.py).
    decimate_sensor: bool = True

    def parameters(self) -> list[tuple[str, Any, str]]:
        """(name, value, description) of the read-only node parameters that show these settings."""
        return [("rate", self.rate_hz, "setpoint rate, Hz"), ("profile", self.profile.name, "stream QoS profile"),
                ("pattern", self.pattern, "setpoint pattern"), ("altitude", self.altitude, "m above home"),
                ("size", self.size, "pattern size, m"), ("speed", self.speed, "pattern speed, m/s"),
                ("formation", self.formation, "none, line or grid"), ("spacing", self.spacing, "m between slots"),
                ("drones", ",".join(self.drones), "drones given (empty: discovered)"),
                ("client_id", self.client_id, "id carried by setpoints and commands"),
                ("image_mode", self.profile.image_mode, "how images arrive"),
                ("sensor_rate", self.sensor_rate_hz or 0.0, "sensor rate asked of each drone, Hz (0: not asked)"),
                ("camera_rate", self.camera_rate_hz or 0.0, "camera rate asked of each drone, fps (0: not asked)"),
                ("decimate_sensor", self.decimate_sensor, "ask a drone for less sensor when this GCS cannot keep up")]
