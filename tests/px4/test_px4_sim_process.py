"""The simulator as a real process: ``python -m px4_link.sim``, SIGKILL and restart."""
from __future__ import annotations

import signal
import subprocess

import pytest
from px4_helpers import EventLog, sim_process, wait_armable, wait_for

from px4_link import Px4Link
from px4_link.sim.cli import build_parser


def _kill(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(signal.SIGKILL)
    p.wait(timeout=5)


def test_simulator_killed_and_restarted_link_reconnects() -> None:
    events = EventLog()
    with Px4Link("udpin:127.0.0.1:0", heartbeat_timeout=1.0, on_event=events) as link:
        first = sim_process(7, link.local_port)
        try:
            assert link.wait_connected(15), first.stdout.read() if first.poll() is not None else ""
            assert link.system_id == 7
            wait_armable(link)
            link.action.arm()
            assert link.wait_until(lambda: link.state.armed, 3)
        finally:
            _kill(first)
        assert wait_for(lambda: not link.connected, 1.0 + 2.0)
        assert "disconnected" in events.names()
        second = sim_process(7, link.local_port)   # new process, new ephemeral source port
        try:
            assert link.wait_connected(15)
            # A starved start-up can go silent past the 1 s watchdog once more and come back: every
            # reconnect is a "connected" event, and there is at least the one the restart caused.
            assert link.stats.reconnects >= 1
            # (the event is emitted just after the state changes: wait for it)
            assert wait_for(lambda: events.count("connected") == link.stats.reconnects + 1, 3)
            # A restarted PX4 is disarmed; and our commands reach the NEW process.
            assert link.wait_until(lambda: not link.state.armed, 3)
            wait_armable(link)
            link.action.arm()
            assert link.wait_until(lambda: link.state.armed, 3)
        finally:
            _kill(second)
        out = second.stdout.read()
        assert "sysid=7" in out and "port=" in out


def test_cli_parses_ports_params_and_rates() -> None:
    a = build_parser().parse_args(["--sysid", "3", "--port", "0", "--target-port", "14600",
                                   "--param", "COM_OBL_RC_ACT=5", "--rate", "highres_imu=200"])
    assert (a.sysid, a.port, a.target_port) == (3, 0, 14600)
    assert dict(a.param) == {"COM_OBL_RC_ACT": 5.0} and dict(a.rate) == {"HIGHRES_IMU": 200.0}
    d = build_parser().parse_args([])
    assert (d.port, d.target_port, d.sysid) == (14580, 14540, 1)   # PX4 SITL's offboard link
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--param", "NOVALUE"])


def test_cli_rejects_unknown_parameter() -> None:
    p = sim_process(9, 9, "--param", "NOT_A_PARAM=1")
    try:
        assert p.wait(timeout=15) == 2
        assert "NOT_A_PARAM" in p.stdout.read()
    finally:
        _kill(p)
