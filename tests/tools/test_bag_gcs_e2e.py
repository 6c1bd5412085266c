"""The GCS's flight-log extras end to end: ``gcs --record FILE.mcap``, ``--mavlink-out``, ``--foxglove``.

Real parts: a companion process on the built-in PX4 simulator (``--px4 sim``) with its MAVLink
tunnel, GCS processes as an operator starts them, the mcap reader, a UDP socket standing in
for QGroundControl, a WebSocket client speaking Foxglove's protocol. The processes share a
random domain (ZR_DOMAIN) so they never meet other tests' systems.
"""
from __future__ import annotations

import asyncio
import json
import secrets
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
from conftest import CLI, ROOT, free_port, fresh_domain, python_proc, stop_process
from mcap.reader import make_reader  # noqa: E402

DOMAIN = str(fresh_domain())
ENV = {"ZR_DOMAIN": DOMAIN}


def _strict(text: str) -> object:
    def refuse(constant: str) -> object:
        raise ValueError(f"not strict JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


def _stop(proc: subprocess.Popen, timeout: float = 20.0) -> str:
    return stop_process(proc, timeout)


@pytest.fixture(scope="module")
def drone() -> Iterator[str]:
    drone_id = f"e{secrets.token_hex(3)}"
    proc = python_proc("-m", "companion", "--id", drone_id, "--px4", "sim", "--camera-rate", "5",
                       "--mavlink-tunnel", "--duration", "170", env=ENV)
    try:
        yield drone_id
    finally:
        out = _stop(proc)
        assert "Traceback" not in out, out[-3000:]


def _gcs(drone_id: str, *args: str) -> subprocess.Popen:
    return python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", "tester@e2e", "--drones", drone_id, *args, env=ENV)


def test_gcs_record_writes_a_flight_log_with_positions_and_a_strict_summary(drone, tmp_path):
    path = tmp_path / "flight.mcap"
    # 2 m: the climb above 1 m and the landing it checks, without PX4's slow descent from the default 5 m
    gcs = _gcs(drone, "--mission", "--duration", "3", "--pattern", "hover", "--altitude", "2", "--record", str(path))
    try:
        out, _ = gcs.communicate(timeout=90)
    finally:
        if gcs.poll() is None:
            _stop(gcs)
    assert gcs.returncode == 0, out[-3000:]
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "the GCS finished the file (index, footer)"
        topics = {c.topic for c in summary.channels.values()}
        assert {f"/{drone}/state", f"/{drone}/state/pose", f"/{drone}/setpoint", f"/_zr/raw/{drone}/state"} <= topics
        heights = [-json.loads(m.data)["position"][2] for _, _, m in reader.iter_messages(topics=[f"/{drone}/state"])]
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    # the hover was flown: the recorded states climb above 1 m (NED: up is -z) and back down
    assert len(heights) > 10 and max(heights) > 1.0 and heights[0] < 0.5, heights[:5]
    gcs_summary = _strict(meta["gcs.summary"]["json"])
    assert drone in gcs_summary["drones"] and gcs_summary["mission"]["ok"] is True
    assert int(meta["zenoh_robot.recording"]["dropped"]) == 0
    _strict(path.with_suffix(".summary.json").read_text())     # the figures beside it, strict too
    info = subprocess.run([*CLI, "bag", "info", "--json", str(path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=30)
    assert info.returncode == 0 and _strict(info.stdout)["complete"] is True, info.stderr


@dataclass
class LiveGcs:
    """One GCS process with both live outputs on: a MAVLink stream to a local QGC port and Foxglove."""
    proc: subprocess.Popen
    qgc: socket.socket
    foxglove_port: int
    output: list[str] = field(default_factory=list)

    def out(self) -> str:
        """What the GCS printed (it is stopped first: its output is read once it ended)."""
        if not self.output:
            self.output.append(_stop(self.proc))
        return self.output[0]


@pytest.fixture(scope="module")
def live_gcs(drone) -> Iterator[LiveGcs]:
    qgc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    qgc.bind(("127.0.0.1", 0))
    qgc.settimeout(1.0)
    port = free_port()
    gcs = _gcs(drone, "--duration", "60", "--mavlink-out", f"udpout:127.0.0.1:{qgc.getsockname()[1]}",
               "--foxglove", str(port))
    live = LiveGcs(gcs, qgc, port)
    try:
        yield live
    finally:
        live.out()
        qgc.close()


def test_mavlink_tunnel_reaches_a_local_qgc_port(live_gcs):
    from pymavlink.dialects.v20 import common as mavlink2

    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    heartbeats = []
    deadline = time.monotonic() + 40
    while len(heartbeats) < 2 and time.monotonic() < deadline and live_gcs.proc.poll() is None:
        try:
            data = live_gcs.qgc.recv(65535)
        except TimeoutError:
            continue
        for msg in parser.parse_buffer(data) or []:
            if msg.get_type() == "HEARTBEAT":
                heartbeats.append(msg)
    assert len(heartbeats) >= 2, live_gcs.out()[-3000:]
    # PX4's own heartbeat (the simulator's system 1, an autopilot), byte for byte through Zenoh
    assert any(h.get_srcSystem() == 1 and h.autopilot == mavlink2.MAV_AUTOPILOT_PX4 for h in heartbeats), heartbeats


def test_gcs_foxglove_serves_the_live_view(drone, live_gcs):
    from foxglove_client import watch

    port = live_gcs.foxglove_port
    pose = f"/{drone}/state/pose"
    channels, _ = asyncio.run(watch(port, 30.0, lambda channels, got: pose in channels, retry_connect=True))
    assert f"/{drone}/state/pose" in channels and f"/{drone}/state" in channels, \
        (sorted(channels), live_gcs.out()[-2000:])
    assert channels[f"/{drone}/state"]["schemaName"] == "zenoh_robot/VehicleState"
    assert channels[f"/{drone}/state/pose"]["schemaName"] == "foxglove.PoseInFrame"
