"""The apps say at start what protects commands: one WARNING line in the default profile
(unauthenticated: a client id is a claim), another line under --secure (mTLS + ACL, the
certificate). And a mission over a network is not one flag away from open.

Real processes: the companion (built-in simulator), the GCS and `gcs cmd`, each in its own domain.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

from conftest import fresh_domain, python_proc

from drone_contract.link_protection import UNAUTHENTICATED, reaches_network, startup_line
from zenoh_robot import SessionConfig

CLI = ("-m", "zenoh_robot.tools.cli.main")


def _programs(drone: str, *session: str) -> dict[str, subprocess.Popen]:
    local = ("--listen", "tcp/127.0.0.1:0", *session)
    return {
        "companion": python_proc(*CLI, "companion", "--id", drone, "--px4", "sim", "--camera", "none",
                                 "--duration", "1", *local),
        "gcs": python_proc(*CLI, "gcs", "--drones", drone, "--no-dashboard", "--duration", "1", *local),
        "gcs cmd": python_proc(*CLI, "gcs", "cmd", drone, "hold", "--timeout", "1", *local),
    }


def _outputs(procs: dict[str, subprocess.Popen]) -> dict[str, str]:
    return {name: p.communicate(timeout=90)[0] for name, p in procs.items()}


def _protection_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if "link protection:" in line]


def test_default_profile_says_once_that_commands_are_unauthenticated():
    domain = str(fresh_domain())
    for name, out in _outputs(_programs("uav1", "--domain", domain)).items():
        lines = _protection_lines(out)
        assert len(lines) == 1, f"{name}: {out}"
        assert "WARNING" in lines[0] and UNAUTHENTICATED in lines[0] and "--secure" in lines[0], f"{name}: {out}"


def test_secure_says_which_protection_is_on(tmp_path: Path):
    import cryptography  # noqa: F401  (a dev dependency: missing is a failure)

    from zenoh_robot.tools import keys
    keys.init_ca(tmp_path)
    keys.issue(tmp_path, "uav1", "drone")
    keys.issue(tmp_path, "gcs", "gcs", drones=["uav1"])
    domain = str(fresh_domain())
    procs = _programs("uav1", "--domain", domain, "--secure", str(tmp_path))
    # The certificate defaults to the node's id: the companion's is its drone id, the GCS's "gcs".
    for name, out in _outputs(procs).items():
        lines = _protection_lines(out)
        assert len(lines) == 1, f"{name}: {out}"
        assert UNAUTHENTICATED not in out, f"{name}: {out}"
        cert = "uav1" if name == "companion" else "gcs"
        assert "mTLS + ACL" in lines[0] and f"certificate {cert!r}" in lines[0], f"{name}: {lines[0]}"
        assert "INFO" in lines[0]


def test_a_mission_over_a_network_needs_secure_or_insecure_ok():
    # --connect to another host without --secure: refused before any session opens.
    p = python_proc(*CLI, "gcs", "--drones", "uav1", "--mission", "--no-dashboard", "--duration", "1",
                    "--connect", "tcp/192.0.2.1:7447", "--domain", str(fresh_domain()))
    out = p.communicate(timeout=60)[0]
    assert p.returncode == 2, out
    assert "--insecure-ok" in out and "--secure" in out, out
    # What counts as a network: multicast on an interface, a non-loopback connect endpoint.
    assert not reaches_network(SessionConfig())                     # the default: `make demo`, the tests
    assert not reaches_network(SessionConfig(connect=["tcp/127.0.0.1:7447", "udp/[::1]:7447"]))
    assert reaches_network(SessionConfig(connect=["tcp/192.0.2.1:7447"]))
    assert reaches_network(SessionConfig(connect=["tcp/drone1.local:7447"]))
    assert reaches_network(SessionConfig.resilient("lo"))
    level, line = startup_line(SessionConfig(listen=["tls/127.0.0.1:0"], connect=[]))
    assert UNAUTHENTICATED in line and "session file" in line    # TLS alone is not the ACL
