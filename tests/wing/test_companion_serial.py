"""The companion with PX4 on a serial port: its start-up mistakes, and a real companion process on a
pseudo-terminal (tests/pty_px4.py): a GCS mission flown through it, and its flight controller unplugged
and plugged back in, as the GCS sees it: the state, the events, a command refused with the reason."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from conftest import fresh_domain, python_proc, stop_process, wait_for
from pty_px4 import PtyWire

from drone_contract.messages import Command, CommandResult, FailsafeEvent, VehicleState
from drone_contract.streams import stream_profile
from px4_link.sim import Simulator
from zenoh_robot import Node

ROOT = Path(__file__).resolve().parents[2]
FAST = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.0}   # shorter climbs and landings; failsafes untouched
OP = "test-op"
QOS = stream_profile("resilient").qos


@pytest.fixture(autouse=True)
def own_domain(monkeypatch: pytest.MonkeyPatch) -> None:
    """This module's processes (nodes ``companion``, ``gcs``) in a Zenoh domain of their own: a
    companion or GCS of a test running beside them would make one refuse to start."""
    monkeypatch.setenv("ZR_DOMAIN", str(fresh_domain()))


class Observer:
    """A test-side node: the drone's state and events, and its command service."""

    def __init__(self, node: Node, drone_id: str) -> None:
        self.state: VehicleState | None = None
        self.events: list[FailsafeEvent] = []
        node.create_subscription(VehicleState, f"/{drone_id}/state", self._on_state, QOS["state"])
        node.create_subscription(FailsafeEvent, f"/{drone_id}/events", self.events.append, QOS["events"])
        self.client = node.create_client(f"/{drone_id}/command", Command, CommandResult)
        threading.Thread(target=node.spin, daemon=True).start()

    def _on_state(self, msg: VehicleState) -> None:
        self.state = msg

    def command(self, name: str) -> CommandResult:
        return self.client.call(Command(name, 0.0, "", False, OP), timeout=10.0)


@pytest.mark.parametrize(("px4", "says"), [
    ("foo", "'foo' is not a PX4 connection; expected one of: /dev/ttyACM0[:BAUD]"),
    ("/dev/ttyUSB0", "no serial device /dev/ttyUSB0: is the flight controller plugged in"),
    ("/dev/ttyAMA0:1234", "1234 is not a serial baud rate"),
    ("/etc/hostname", "/etc/hostname is not a serial device"),
    ("serial://ttyACM0", "a serial URL names a device"),
    ("udp://:70000", "port 0..65535"),
])
def test_a_wrong_px4_is_one_line_and_exit_2(px4: str, says: str) -> None:
    r = subprocess.run([sys.executable, "-m", "companion", "--px4", px4, "--camera", "none", "--duration", "1"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and says in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_companion_on_a_serial_port_survives_an_unplug(ns: str, tmp_path: Path) -> None:
    device = tmp_path / "usb-PX4_FMU"     # as /dev/serial/by-id/usb-... : the node behind it changes
    wire = PtyWire()
    device.symlink_to(wire.path)
    with Simulator(1, port=0, target_port=wire.udp_port, params=FAST) as sim, Node("observer") as node:
        wire.attach(sim.port)
        proc = python_proc("-m", "companion", "--id", ns, "--px4", str(device), "--camera", "none")
        replugged: PtyWire | None = None
        try:
            obs = Observer(node, ns)
            assert wait_for(lambda: obs.state is not None and obs.state.connected, 20), "no state from the drone"

            wire.unplug()
            assert wait_for(lambda: obs.state is not None and not obs.state.connected, 10)
            assert wait_for(lambda: any(e.kind == "px4_disconnected" and "vanished" in e.detail
                                        for e in obs.events), 5), [(e.kind, e.detail) for e in obs.events]
            res = obs.command("arm")
            assert not res.success and f"serial device {device} vanished" in res.message, res.message

            replugged = PtyWire(udp_port=wire.udp_port)
            fresh = tmp_path / "usb-PX4_FMU.new"
            fresh.symlink_to(replugged.path)
            os.replace(fresh, device)
            replugged.attach(sim.port)
            assert wait_for(lambda: obs.state is not None and obs.state.connected, 10)
            assert wait_for(lambda: any(e.kind == "px4_reconnected" for e in obs.events), 5)
        finally:
            out = stop_process(proc, 10.0)
            if replugged is not None:
                replugged.close()
        assert "Traceback" not in out, out


def test_a_mission_flies_over_a_serial_port(ns: str, tmp_path: Path) -> None:
    record = tmp_path / "gcs.json"
    wire = PtyWire()
    with Simulator(1, port=0, target_port=wire.udp_port, params=FAST) as sim:
        wire.attach(sim.port)
        proc = python_proc("-m", "companion", "--id", ns, "--px4", f"serial://{wire.path}:921600",
                           "--camera-rate", "5")
        try:
            gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", ns, "--mission",
                              "--duration", "4", "--pattern", "square", "--size", "4", "--altitude", "2.5",
                              "--record", str(record))
            out, _ = gcs.communicate(timeout=120)
            assert gcs.returncode == 0, out
            modes = [m.new for m in sim.mode_log]
        finally:
            companion_out = stop_process(proc, 10.0)
            wire.close()
    assert "Traceback" not in companion_out, companion_out
    summary = json.loads(record.read_text())
    assert summary["mission"]["ok"], summary["mission"]
    assert "OFFBOARD" in modes and modes[-1] in ("AUTO.LAND", "AUTO.LOITER")
    d = summary["drones"][ns]
    assert d["max_path_error_m"] < 3.0
    assert d["final_state"]["landed"] and not d["final_state"]["armed"]
