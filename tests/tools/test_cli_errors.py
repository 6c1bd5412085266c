"""A user's mistake ends a command with one line and a non-zero exit, never a traceback;
the terminal stays clean (no Zenoh log lines); usage errors name the subcommand."""
from __future__ import annotations

import socket
import subprocess

import pytest
from cli_helpers import ROOT, cli


def one_line_error(r: subprocess.CompletedProcess, *needles: str) -> None:
    assert r.returncode not in (0, None), r
    assert "Traceback" not in r.stderr, r.stderr
    lines = [line for line in r.stderr.strip().splitlines() if line]
    assert len(lines) == 1, r.stderr
    for n in needles:
        assert n in lines[0], r.stderr


def test_version():
    r = cli("--version")
    assert r.returncode == 0 and r.stdout.startswith("zenoh-robot ")


def test_a_subcommand_usage_error_prints_the_subcommand_usage():
    r = cli("topic", "echo", "/x", "--bogus")
    assert r.returncode == 2
    assert "usage: zenoh-robot topic echo" in r.stderr and "unrecognized arguments: --bogus" in r.stderr


def test_simulator_on_a_busy_port_is_one_line():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        r = cli("sim", "--port", str(port))
    one_line_error(r, "address already in use")


@pytest.mark.parametrize("args, needle", [
    (["gcs", "cmd", "uav1", "takeoff", "abc"], "abc"),
    (["gcs", "--zenoh", "/nonexistent.json5"], "/nonexistent.json5"),
    (["gcs", "cmd", "uav1", "arm", "--zenoh", "/nonexistent.json5"], "/nonexistent.json5"),
    (["companion", "--zenoh", "/nonexistent.json5"], "/nonexistent.json5"),
    (["companion", "--config", "/nonexistent.yaml", "--px4", "udpin:127.0.0.1:1"], "/nonexistent.yaml"),
    (["topic", "list", "--zenoh", "/nonexistent.json5"], "/nonexistent.json5"),
    (["topic", "pub", "/x", "NoSuchType"], "unknown message type"),
    (["topic", "pub", "/x", "std_msgs/String", "{data: hi}", "--once", "--qos-reliability", "reliable",
      "--qos-depth=-3"], "--qos-depth"),
    (["topic", "echo", "/x", "--filter", "__import__('os').system('true')", "--duration", "1"], "--filter"),
    (["launch", "/nonexistent.yaml"], "/nonexistent.yaml"),
])
def test_user_errors_are_one_line(args, needle):
    one_line_error(cli(*args), needle)


def test_the_session_config_flag_is_zenoh_only():
    r = cli("topic", "list", "--config", "/nonexistent.json5")
    assert r.returncode != 0 and "unrecognized arguments: --config" in r.stderr


def test_zenoh_log_stays_off_the_terminal():
    # A connect endpoint nobody listens on makes Zenoh log warnings/errors at start-up.
    cfg = ROOT / "tests" / "_unreachable.json5"
    cfg.write_text('{mode: "peer", connect: {endpoints: ["tcp/127.0.0.1:9"]}, listen: {endpoints: '
                   '["tcp/127.0.0.1:0"]}, scouting: {multicast: {enabled: false}}}')
    try:
        r = cli("topic", "list", "--zenoh", str(cfg), "--timeout", "1")
        assert "\x1b[" not in r.stdout + r.stderr
        assert "zenoh::" not in r.stdout + r.stderr, r.stdout + r.stderr
        v = cli("-v", "topic", "list", "--zenoh", str(cfg), "--timeout", "1")
        assert "\x1b[" not in v.stdout + v.stderr   # -v shows Zenoh's warnings, without colour codes
    finally:
        cfg.unlink()


def test_completion_script_knows_the_commands(tmp_path):
    r = cli("completion", "bash")
    assert r.returncode == 0
    script = tmp_path / "c.sh"
    script.write_text(r.stdout)
    out = subprocess.run(["bash", "-c", f"source {script}; COMP_WORDS=(zenoh-robot topic e); COMP_CWORD=2; "
                          "_zenoh_robot; echo ${COMPREPLY[@]}"], capture_output=True, text=True, timeout=30)
    assert out.stdout.split() == ["echo"], out


def test_filter_is_never_evaluated_as_code():
    from zenoh_robot.tools.cli.fields import Filter, FilterError
    data = {"x": 2.0, "header": {"seq": 4}, "gyro": [0.1, 0.2]}
    assert Filter("x > 1 and header.seq % 2 == 0")(data)
    assert Filter("m.gyro[1] > 0.15 and len(gyro) == 2")(data)
    assert not Filter("x > 3")(data)
    assert not Filter("nosuchfield > 1")(data)      # a field the message lacks: not shown
    for bad in ("__import__('os')", "x.__class__", "(lambda: 1)()", "open('/etc/passwd')", "[i for i in gyro]"):
        with pytest.raises(FilterError):
            Filter(bad)
    assert not Filter("'a' * 10 ** 9 == 1")(data)   # refused at run time, no memory blow-up


def test_a_second_companion_on_a_px4_port_in_use_stops_with_one_line():
    """Two links on one vehicle's port would cross its datagrams (the first companion's replies and the
    second's): the port is bound exclusively, and the second start says why in one line."""
    from px4_link.transport import UdpServerTransport
    first = UdpServerTransport("127.0.0.1", 0)       # as a running companion holds it
    try:
        port = first.local_address[1]
        with pytest.raises(OSError):
            UdpServerTransport("127.0.0.1", port)
        r = cli("companion", "--id", "tbusy", "--px4", f"udpin:127.0.0.1:{port}", "--duration", "5")
    finally:
        first.sock.close()
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("zenoh-robot companion: address already in use"), r.stderr
