"""The GCS's settings: one dataclass, what the CLI validated (gcs/cli.py) and the app runs with."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

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
