"""``zenoh-robot keys`` and ``zenoh-robot router`` as real processes, the secure system end to end."""
from __future__ import annotations

import signal
import stat
import time
from pathlib import Path

import pytest
import zenoh
from cli_helpers import CLI_ARGS, cli
from conftest import free_port, python_proc, wait_for

from zenoh_robot.session_config import SessionConfig  # noqa: E402


def test_keys_cli_then_secure_router_process(tmp_path: Path) -> None:
    d = tmp_path / "keys"
    assert cli("keys", "init", str(d)).returncode == 0
    for args in (("router", "--role", "router"), ("gcs", "--role", "gcs", "--drones", "uav1"),
                 ("uav1", "--role", "drone")):
        res = cli("keys", "issue", *args, "--dir", str(d))
        assert res.returncode == 0, res.stdout
    assert stat.S_IMODE((d / "uav1.key").stat().st_mode) == 0o600
    assert (d / "gcs.json5").is_file()
    listed = cli("keys", "list", str(d)).stdout
    assert "uav1" in listed and "drone" in listed and "-> uav1" in listed
    assert cli("keys", "init", str(d)).returncode == 1     # never silently replaces a CA

    port = free_port()
    router = python_proc(*CLI_ARGS, "router", "--secure", str(d), "--listen", f"tls/127.0.0.1:{port}",
                         "--no-scouting", "--status", "0", "--duration", "30")
    sessions: list[zenoh.Session] = []
    try:
        first = router.stdout.readline()
        assert "secure" in first and f"tls/127.0.0.1:{port}" in first, first
        ep = f"tls/127.0.0.1:{port}"
        for name in ("uav1", "gcs"):
            sessions.append(zenoh.open(SessionConfig(secure=str(d), name=name, mode="client", listen=[],
                                                     connect=[ep], multicast_scouting=False).to_zenoh()))
        got: list[bytes] = []
        sessions[0].declare_subscriber("uav1/setpoint", lambda s: got.append(s.payload.to_bytes()))
        lines: list[str] = []
        while not any("router: 2 connected" in x for x in lines):   # bounded by the router's --duration
            line = router.stdout.readline()
            if not line:
                break
            lines.append(line)
        status = next(x for x in lines if "router: 2 connected" in x)
        assert status.count("client") == 2 and "127.0.0.1" in status, status
        time.sleep(0.3)
        sessions[1].put("uav1/setpoint", b"go")
        assert wait_for(lambda: got == [b"go"], 5.0)
        router.send_signal(signal.SIGINT)
        out, _ = router.communicate(timeout=15)
        assert router.returncode == 0 and "router: closed" in out
    finally:
        for s in sessions:
            s.close()
        if router.poll() is None:
            router.kill()
            router.wait()


def test_router_refuses_a_plain_endpoint_when_secure(tmp_path: Path) -> None:
    d = tmp_path / "keys"
    assert cli("keys", "init", str(d)).returncode == 0
    assert cli("keys", "issue", "router", "--role", "router", "--dir", str(d)).returncode == 0
    res = cli("router", "--secure", str(d), "--listen", "tcp/127.0.0.1:0", "--duration", "1", merged=True)
    assert res.returncode == 1 and "plain links are refused" in res.stdout


@pytest.mark.fast
def test_lossy_router_config_forms_sessions_across_loss() -> None:
    """``router --lossy``: the ground router of a swarm on a radio link tries handshakes fast (250 ms
    tries, retries from 50 ms) and holds its lease with keep-alives every 100 ms; plain stays Zenoh's."""
    import argparse

    from zenoh_robot.tools.cli.router import register, router_config

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    lossy = router_config(parser.parse_args(["router", "--lossy", "--listen", "udp/127.0.0.1:7447"]))
    values = lossy._values()
    assert values["transport/unicast/open_timeout"] == 250
    assert values["connect/retry"]["period_init_ms"] == 50
    assert values["transport/link/tx/keep_alive"] == 100 and values["transport/link/tx/batch_size"] == 1300
    lossy.to_zenoh()                       # Zenoh accepts every key
    from drone_contract.streams import stream_profile
    apps = stream_profile("resilient").session_config()   # the router tunes the link as the apps do
    assert (lossy.batch_size, lossy.lease_s, lossy.keep_alive, lossy.lossy) == \
        (apps.batch_size, apps.lease_s, apps.keep_alive, apps.lossy)
    plain = router_config(parser.parse_args(["router"]))._values()
    assert "transport/unicast/open_timeout" not in plain and "transport/link/tx/keep_alive" not in plain
