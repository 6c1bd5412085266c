"""The companion asks PX4 only for the telemetry it reads (issue #18: px4_streams lean).

Against the simulator, which answers MAV_CMD_SET_MESSAGE_INTERVAL as PX4 does: the lean
streams arrive at the rates asked (measured over a few seconds, generous bounds), the unused
ones stop, a rebooted PX4 is asked again, and with the MAVLink tunnel nothing is cut.
"""
from __future__ import annotations

import json
import secrets
import subprocess
import time
from pathlib import Path

import pytest
from conftest import free_port, python_proc
from px4_helpers import sim_and_link

from companion.telemetry_bridge import LEAN_STREAMS_HZ, ask_streams
from px4_link import CommandFailed
from px4_link.sim import Simulator
from px4_link.wire import mavlink2, message_id
from zenoh_robot import SessionConfig

SETTLE_S = 3.5    # longer than the measuring window: no arrival from before the change is counted
WINDOW_S = 3.0


def _interval(link, name: str, interval_us: float, *extra: float) -> None:
    link.send_command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, message_id(name), interval_us, *extra)


def test_the_simulator_answers_set_message_interval_as_px4() -> None:
    with sim_and_link() as (sim, link, _):
        _interval(link, "ATTITUDE", 1e5)                       # 10 Hz
        assert sim.message_rates["ATTITUDE"] == pytest.approx(10.0)
        _interval(link, "ATTITUDE", -1)                        # off
        assert sim.message_rates["ATTITUDE"] == 0.0
        _interval(link, "ATTITUDE", 0)                         # PX4's default again
        assert sim.message_rates["ATTITUDE"] == 100.0
        _interval(link, "ODOMETRY", -1)                        # a PX4 stream the simulator never sends
        assert sim.not_simulated_intervals == {"ODOMETRY": -1.0}
        for name, extra in (("HEARTBEAT", ()), ("ATTITUDE", (0, 0, 0, 0, 1))):
            with pytest.raises(CommandFailed):                 # no stream / a response target: FAILED
                _interval(link, name, 1e5, *extra)
        assert sim.message_rates["ATTITUDE"] == 100.0


def _rates(link) -> dict[str, float]:
    return {n: link.telemetry.rate_hz(n, WINDOW_S) for n in
            ("ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "VFR_HUD", "GPS_RAW_INT",
             "EXTENDED_SYS_STATE")}


def _assert_lean(rates: dict[str, float]) -> None:
    # Upper bounds are what lean promises; lower bounds only say the stream still flows (a loaded
    # machine may starve the simulator's thread, never make it send faster than asked).
    assert 2.0 <= rates["ATTITUDE"] <= 15.0, rates                 # asked 10 Hz (PX4 default 100)
    assert 4.0 <= rates["LOCAL_POSITION_NED"] <= 27.0, rates       # asked 20 Hz (default 30)
    assert 0.3 <= rates["GLOBAL_POSITION_INT"] <= 2.0, rates       # asked 1 Hz (default 50)
    assert rates["VFR_HUD"] == 0.0 and rates["GPS_RAW_INT"] == 0.0, rates   # off
    assert rates["EXTENDED_SYS_STATE"] > 1.0, rates                # not asked: PX4's 5 Hz


def test_lean_streams_arrive_at_the_asked_rates_and_are_asked_again_after_a_reboot() -> None:
    with sim_and_link() as (sim, link, events):
        assert link.wait_until(lambda: link.telemetry.rate_hz("ATTITUDE", 1.0) > 30, 5.0)   # default first
        assert ask_streams(link, LEAN_STREAMS_HZ) == {}
        assert sim.message_rates["ATTITUDE"] == 10.0 and sim.message_rates["VFR_HUD"] == 0.0
        time.sleep(SETTLE_S)
        _assert_lean(_rates(link))

        port, target = sim.port, link.local_port
        sim.stop()                                   # PX4 reboots: it forgets every interval asked
        with Simulator(1, port=port, target_port=target, seed=3) as sim2:
            assert sim2.wait_for(lambda s: s.message_rates["ATTITUDE"] == 10.0
                                 and s.message_rates["VFR_HUD"] == 0.0
                                 and s.not_simulated_intervals.get("ODOMETRY") == -1.0, 8.0), \
                f"the rebooted PX4 was not asked again: {sim2.message_rates}"
            # Seen by the reboot watch on the 10 Hz ATTITUDE, or as a reconnect: either re-asks.
            assert "rebooted" in events.names() or "connected" in events.names()[1:]
            time.sleep(SETTLE_S)
            _assert_lean(_rates(link))


# ---------------------------------------------------------------- the companion process
def _companion(tmp: Path, name: str, *extra: str) -> tuple[subprocess.Popen[str], Path]:
    zenoh = tmp / f"{name}.json5"
    session = SessionConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], multicast_scouting=False)
    zenoh.write_text(json.dumps(session.to_json5()))
    record = tmp / f"{name}.json"
    proc = python_proc("-m", "companion", "--id", f"ts{secrets.token_hex(3)}", "--px4", "sim",
                       "--camera", "none", "--sensor-rate", "50", "--no-topic-statistics",
                       "--zenoh", str(zenoh), "--duration", "7", "--record", str(record), *extra)
    return proc, record


def test_the_companion_asks_lean_streams_and_cuts_nothing_with_the_mavlink_tunnel(tmp_path: Path) -> None:
    lean, lean_rec = _companion(tmp_path, "lean")
    tunnel, tunnel_rec = _companion(tmp_path, "tunnel", "--mavlink-tunnel")
    outs = [p.communicate(timeout=60)[0] for p in (lean, tunnel)]
    for p, out in zip((lean, tunnel), outs, strict=True):
        assert p.returncode == 0 and "Traceback" not in out, out
    assert "PX4 streams asked (lean)" in outs[0], outs[0]
    assert "not applied: the MAVLink tunnel" in outs[1], outs[1]

    got = json.loads(lean_rec.read_text())["px4_streams"]
    assert got["in_force"] == "lean" and got["refused"] == {}
    assert got["asked_hz"] == LEAN_STREAMS_HZ
    rates = got["delivered_hz"]    # over the last 2 s, long after the streams were asked
    assert 2.0 <= rates["ATTITUDE"] <= 15.0 and rates["VFR_HUD"] == 0.0, rates
    assert 20.0 <= rates["HIGHRES_IMU"] <= 60.0, rates      # --sensor-rate 50: asked on its own

    got = json.loads(tunnel_rec.read_text())["px4_streams"]
    assert got["in_force"] == "default" and got["asked_hz"] == {}
    rates = got["delivered_hz"]
    assert rates["ATTITUDE"] > 30.0 and rates["VFR_HUD"] > 3.0 and rates["GLOBAL_POSITION_INT"] > 15.0, rates


def test_a_bad_px4_streams_value_is_refused_before_anything_starts() -> None:
    p = python_proc("-m", "companion", "--px4", "udpin:127.0.0.1:1", "--camera", "none",
                    "-p", "px4_streams:=none")
    out = p.communicate(timeout=60)[0]
    assert p.returncode not in (0, None) and "Traceback" not in out, out
    assert "px4_streams: 'none': one of lean, default" in out, out
