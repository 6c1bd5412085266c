"""The companion's parameters through the real CLI, against a real companion process (--px4 sim),
over Zenoh on loopback; and its end-of-run summary when PX4 never answers."""
from __future__ import annotations

import json
import secrets
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from cli_helpers import cli
from conftest import free_port, python_proc, wait_for

from companion.params import SPECS, qos_param_names
from drone_contract.messages import CONTROL_TOKEN_PREFIX, Command, CommandResult, FailsafeEvent, VehicleState
from drone_contract.streams import stream_profile
from zenoh_robot import Node, SessionConfig

OPERATOR = "tester"   # the client id the test's sets carry; it takes control first (safety limits: holder only)


def _strict_json(text: str) -> object:
    def no_constant(name: str) -> object:
        raise AssertionError(f"{name} in a summary file: not JSON")
    return json.loads(text, parse_constant=no_constant)


class Drone:
    def __init__(self, tmp: Path) -> None:
        self.id = f"tp{secrets.token_hex(3)}"
        port = free_port()
        self.listen = SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False)
        self.connect = SessionConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False)
        self.companion_zenoh = tmp / "companion.json5"
        self.client_zenoh = tmp / "client.json5"
        self.companion_zenoh.write_text(json.dumps(self.listen.to_json5()))
        self.client_zenoh.write_text(json.dumps(self.connect.to_json5()))
        self.record = tmp / "summary.json"
        self.node = f"/{self.id}/companion"

    def param(self, *args: str) -> subprocess.CompletedProcess[str]:
        op, *rest = args
        return cli("param", "--zenoh", str(self.client_zenoh), "--timeout", "10", "--client-id", OPERATOR,
                   op, self.node, *rest)


@pytest.fixture(scope="module")
def drone(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Drone, subprocess.Popen[str]]]:
    d = Drone(tmp_path_factory.mktemp("companion"))
    # -p depth:=1 is the thesis's node parameter; -p max_offset_m:=7 beats the flag's default (10).
    proc = python_proc("-m", "companion", "--id", d.id, "--px4", "sim", "--camera", "none",
                       "--no-topic-statistics", "--zenoh", str(d.companion_zenoh), "--record", str(d.record),
                       "-p", "depth:=1", "-p", "max_offset_m:=7")
    try:
        yield d, proc
    finally:
        if proc.returncode is None:   # the live-change test stops it itself, to read its summary
            proc.send_signal(2)
            out, _ = proc.communicate(timeout=20)
            assert "Traceback" not in out, out


def test_param_list_shows_every_setting_and_the_qos_in_force(drone: tuple[Drone, subprocess.Popen[str]]) -> None:
    d, _ = drone
    r = d.param("list")
    assert r.returncode == 0, r.stderr
    listed = {line.strip() for line in r.stdout.splitlines()}
    assert {s.name for s in SPECS} | set(qos_param_names()) | {"depth"} <= listed
    assert "reliability" not in listed    # the thesis's names appear only when given
    assert d.param("get", "depth").stdout.strip() == "Integer value is: 1"
    assert d.param("get", "qos.sensor.depth").stdout.strip() == "Integer value is: 1"   # applied to the stream
    assert d.param("get", "max_offset_m").stdout.strip() == "Double value is: 7.0"
    desc = d.param("describe", "allow_force_disarm").stdout
    assert "Read only: true" in desc


def test_live_changes_apply_and_bad_values_are_refused(drone: tuple[Drone, subprocess.Popen[str]]) -> None:
    d, proc = drone
    q = stream_profile("resilient").qos
    with Node("observer", config=d.connect) as node:
        events: list[FailsafeEvent] = []
        states: list[VehicleState] = []
        node.create_subscription(FailsafeEvent, f"/{d.id}/events", events.append, q["events"])
        node.create_subscription(VehicleState, f"/{d.id}/state", states.append, q["state"])
        threading.Thread(target=node.spin, daemon=True).start()
        assert wait_for(lambda: bool(states), 20.0), "no VehicleState from the companion"
        assert states[-1].sensor_rate_requested_hz == 200.0
        # As a GCS does: its liveliness token keeps control while the (slow) CLI calls run.
        token = node.declare_liveliness_token(f"{CONTROL_TOKEN_PREFIX}/{OPERATOR}")   # kept: dropped, it goes
        assert token is not None
        commands = node.create_client(f"/{d.id}/command", Command, CommandResult)
        res = commands.call(Command("take_control", 0.0, "", False, OPERATOR), timeout=10.0)
        assert res.success, res.message

        for name, value, why in (("max_offset_m", "500", "outside 0.5..100 m"),
                                 ("max_speed", ".nan", "outside"),
                                 ("allow_force_disarm", "true", "read-only"),
                                 ("param_allow", "[COM_OBL_RC_ACT]", "read-only"),
                                 ("qos.setpoint.depth", "5", "read-only"),
                                 ("max_offset_m", "far", "expected double")):
            r = d.param("set", name, value)
            assert r.returncode != 0 and why in r.stderr, (name, r.stderr)
        assert d.param("get", "max_offset_m").stdout.strip() == "Double value is: 7.0"   # unchanged

        r = d.param("set", "max_offset_m", "4")
        assert r.returncode == 0, r.stderr
        assert d.param("get", "max_offset_m").stdout.strip() == "Double value is: 4.0"
        r = d.param("set", "sensor_rate_hz", "100")
        assert r.returncode == 0, r.stderr
        # Applied, not only stored: the companion reports it and asks PX4 for the new rate.
        assert wait_for(lambda: any(e.kind == "param_changed" and "max_offset_m 7.0 -> 4.0" in e.detail
                                    and e.client_id == OPERATOR
                                    for e in events), 10.0), [e.detail for e in events]
        assert wait_for(lambda: states[-1].sensor_rate_requested_hz == 100.0, 10.0)

    proc.send_signal(2)
    out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0 and "Traceback" not in out, out
    assert f"param_changed [{OPERATOR}]: sensor_rate_hz 200.0 -> 100.0" in out
    assert "no setpoints received" in out and "lost nan" not in out
    summary = _strict_json(d.record.read_text())
    assert isinstance(summary, dict)
    # The companion counts what its checks refused; read-only and type errors stop in the store.
    assert summary["parameters"] == {"changed": 2, "refused": 2}


@pytest.mark.parametrize("args, needle", [
    (["-p", "max_offset_m:=500"], "outside 0.5..100 m"),
    (["-p", "max_ofset_m:=5"], "not a companion parameter"),
    (["-p", "profile:=reliable"], "set by --profile"),
    (["-p", "qos.image.depth:=3"], "shows the QoS in force"),
    (["-p", "param_allow:=[SYS_AUTOSTART, 'x y']"], "not PX4 parameter names"),
])
def test_bad_parameters_fail_before_anything_starts(args: list[str], needle: str) -> None:
    r = cli("companion", "--id", "tbad", "--px4", "udpin:127.0.0.1:1", "--camera", "none", *args)
    assert r.returncode not in (0, None) and "Traceback" not in r.stderr, r.stderr
    assert needle in r.stderr, r.stderr
    assert "PX4 at" not in r.stderr   # refused before PX4 or Zenoh was opened


def test_without_px4_the_summary_says_so(tmp_path: Path) -> None:
    d = Drone(tmp_path)
    silent = free_port()   # nobody sends here: PX4 never shows up
    t0 = time.monotonic()
    r = cli("companion", "--id", d.id, "--px4", f"udpin:127.0.0.1:{silent}", "--camera", "none",
            "--no-topic-statistics", "--zenoh", str(d.companion_zenoh), "--duration", "0.5",
            "--record", str(d.record))
    assert r.returncode == 0, r.stderr
    assert "PX4 never connected" in r.stderr and "nan" not in r.stderr.lower(), r.stderr
    summary = _strict_json(d.record.read_text())
    assert isinstance(summary, dict)
    assert summary["px4"]["ever_connected"] is False and summary["px4"]["connected"] is False
    assert summary["px4"]["backend"] == "mavlink"       # which link to PX4 it was (MAVLink or PX4's Zenoh)
    assert summary["setpoints"]["lost_pct"] is None and summary["sensor_rate_hz"] is None
    assert time.monotonic() - t0 < 60   # a bound against hanging, not a speed claim
