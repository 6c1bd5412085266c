"""The PX4-side Zenoh session: separate from the companion's GCS-facing node.

PX4's zenoh module is a client of a router (``tcp/127.0.0.1:7447`` on SITL, ``zenoh/net.txt``). The
backend either is that router (``--px4 zenoh``: an embedded router listening there, multicast scouting
off so nothing on the airframe's network joins by accident) or a client of an existing one
(``--px4 zenoh:<endpoint>``). Either way it is its own session: PX4's ~880 samples/s and its tokens
never reach the GCS-facing session or its lossy link.
"""
from __future__ import annotations

import json
import socket
from dataclasses import dataclass

import zenoh

PX4_DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"   # PX4 SITL's zenoh/net.txt default


@dataclass(frozen=True)
class Px4Endpoint:
    mode: str        # "router": we listen and PX4 connects; "client": we connect to a router
    endpoint: str

    def __str__(self) -> str:
        return f"zenoh {'router listening on' if self.mode == 'router' else 'client of'} {self.endpoint}"


def parse_px4_spec(spec: str) -> Px4Endpoint | None:
    """``zenoh`` -> embedded router on PX4's default endpoint; ``zenoh:<endpoint>`` -> client of the
    router there; anything else (a MAVLink connection, ``sim``, ``zenoh-sim``) -> None."""
    if spec == "zenoh":
        return Px4Endpoint("router", PX4_DEFAULT_ENDPOINT)
    if spec.startswith("zenoh:"):
        endpoint = spec[len("zenoh:"):]
        if "/" not in endpoint:
            raise ValueError(f"--px4 {spec}: give a Zenoh endpoint, e.g. zenoh:{PX4_DEFAULT_ENDPOINT}")
        return Px4Endpoint("client", endpoint)
    return None


def free_tcp_endpoint() -> str:
    """A loopback endpoint on a free port (for an embedded router that a simulator joins)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def session_config(where: Px4Endpoint) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(where.mode))
    conf.insert_json5("listen/endpoints" if where.mode == "router" else "connect/endpoints",
                      json.dumps([where.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def open_px4_session(where: Px4Endpoint) -> zenoh.Session:
    try:
        return zenoh.open(session_config(where))
    except zenoh.ZError as exc:
        raise ConnectionError(f"PX4 side, {where}: {exc}") from None
