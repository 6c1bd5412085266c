"""The CLI tells a user plainly what went wrong (issue #39): one line on stderr, no traceback, no Rust
source paths, exit 1; and it does not stay silent where something is wrong (an endpoint nobody answers)."""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from cli_helpers import cli


def one_line_error(r: subprocess.CompletedProcess[str], *needles: str) -> str:
    assert r.returncode == 1, r
    assert "Traceback" not in r.stderr + r.stdout, r.stderr
    lines = [line for line in r.stderr.strip().splitlines() if line]
    assert len(lines) == 1, r.stderr
    for needle in needles:
        assert needle in lines[0], r.stderr
    return lines[0]


# -- bag info / bag play of a file that is not a recording ---------------------------------------
def _small_mcap(path: Path) -> bytes:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("test/Thing", "jsonschema", b"{}")
        channel = w.register_channel("/thing", "json", schema)
        for i in range(3):
            w.add_message(channel, log_time=i * 10**8, data=b'{"i": %d}' % i, publish_time=i * 10**8)
        w.finish()
    return path.read_bytes()


@pytest.mark.parametrize("op", ["info", "play"])
@pytest.mark.parametrize("make, needle", [
    (lambda p: p.with_name("x.txt").write_text("hello\n"), "x.txt is not an MCAP file"),
    (lambda p: p.with_name("x.txt").write_bytes(b""), "x.txt is empty: not an MCAP file"),
    (lambda p: None, "x.txt: no such file"),
    (lambda p: p.with_name("x.txt").write_bytes(_small_mcap(p)[:12]), "x.txt is cut short before its first"),
    (lambda p: p.with_name("x.txt").write_bytes(_small_mcap(p)[:5]), "x.txt is cut short"),
], ids=["text", "empty", "missing", "cut-in-header", "cut-in-magic"])
def test_bag_of_a_file_that_is_not_mcap_is_one_line_and_exit_1(tmp_path, op, make, needle):
    make(tmp_path / "made.mcap")
    r = cli("bag", op, str(tmp_path / "x.txt"), timeout=60)
    one_line_error(r, needle)
    assert "published" not in r.stderr and not r.stdout, "no empty bag, no empty replay"


def test_bag_info_of_a_small_recording_still_reads(tmp_path):
    path = tmp_path / "ok.mcap"
    _small_mcap(path)
    r = cli("bag", "info", str(path))
    assert r.returncode == 0 and "/thing" in r.stdout and "Messages:       3" in r.stdout, r


# -- Zenoh config errors: where and what, not Rust's source paths ---------------------------------
@pytest.mark.parametrize("text, needle", [
    ('{\n  mode: "peer",\n  scouting: { multicast: { enabled: false }\n}\n', "never closed (a '}' is missing)"),
    ('{ mode: "peer" ', "the '{' of line 1, column 1 is never closed"),
    ('{ connect: { endpoints: ["tcp/127.0.0.1:7447" } }', "'}' where ']' was expected"),
    ('{ scouting: { multicst: { enabled: false } } }', "unknown field `multicst`"),
    ('{ scouting: { multicast: { enabled: "yes" } } }', 'invalid type: string "yes", expected a boolean'),
    ('{ mode: "pier" }', "unknown variant `pier`"),
    ('{ connect: { endpoints: ["tcp/1.2.3.4"] } }', "missing ':PORT'"),
], ids=["missing-brace", "unclosed", "wrong-closer", "wrong-key", "wrong-type", "wrong-mode", "bad-endpoint"])
def test_a_bad_zenoh_config_file_is_one_line_naming_the_flag_the_file_and_the_problem(tmp_path, text, needle):
    path = tmp_path / "mine.json5"
    path.write_text(text)
    r = cli("topic", "list", "--zenoh", str(path), "--timeout", "1")
    line = one_line_error(r, f"--zenoh {path}:", needle)
    assert ".rs" not in line and "expected boolean or null" not in line and "Message {" not in line, line


def test_a_bad_zenoh_key_given_in_code_is_named_without_rust_paths():
    from zenoh_robot import SessionConfig
    from zenoh_robot.session_config import SessionConfigError

    with pytest.raises(SessionConfigError) as wrong_key:
        SessionConfig(extra={"scouting/multicst/enabled": True}).to_zenoh()
    assert str(wrong_key.value) == "zenoh config scouting/multicst/enabled=True: unknown key"
    with pytest.raises(SessionConfigError) as wrong_type:
        SessionConfig(extra={"scouting/multicast/enabled": "yes"}).to_zenoh()
    assert ".rs" not in str(wrong_type.value) and 'expected a boolean' in str(wrong_type.value)


# -- an endpoint given with -e that nothing answers ------------------------------------------------
@pytest.mark.parametrize("command", [("topic", "list"), ("service", "list", "--timeout", "0.5"),
                                     ("node", "list", "--timeout", "0.5")])
def test_an_endpoint_nobody_answers_is_named_once_on_stderr(own_domain, command):
    from conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = cli(*command, "-e", endpoint)      # the session flags after the operation, as for `topic`
    assert r.returncode == 0 and "Traceback" not in r.stderr, r
    warnings = [line for line in r.stderr.splitlines() if "cannot reach" in line]
    assert warnings == [f"zenoh-robot {command[0]}: cannot reach {endpoint} (is a router running there?)"], r.stderr


def test_an_endpoint_that_answers_gets_no_warning(own_domain):
    from conftest import free_port

    from zenoh_robot.session_config import SessionConfig, open_session

    port = free_port()
    router = open_session(SessionConfig(mode="router", listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False,
                                        shared_memory=False))
    try:
        for args in (("topic", "list", "-e", f"tcp/localhost:{port}"),
                     ("service", "-e", f"tcp/127.0.0.1:{port}", "list", "--timeout", "0.5")):
            r = cli(*args)
            assert r.returncode == 0 and "cannot reach" not in r.stderr, r
    finally:
        router.close()


def test_a_client_whose_router_is_not_there_is_one_line():
    from conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = cli("topic", "list", "-m", "client", "-e", endpoint)
    line = one_line_error(r, f"cannot reach {endpoint} (is a router running there?)")
    assert ".rs" not in line and "Single(" not in line, line


# -- "did you mean" never offers the name typed ----------------------------------------------------
def test_did_you_mean_never_suggests_the_name_typed():
    from zenoh_robot.tools.cli.common import did_you_mean

    assert did_you_mean("/uav1/setpoint", ["/uav1/setpoint"]) == ""
    assert did_you_mean("/uav1/setpoint", ["uav1/setpoint/", "/uav1/setpoint"]) == ""
    assert did_you_mean("/uav1/setpoint", ["/uav1/setpoint", "/uav1/setpoints", "/uav1/setpoints"]) == \
        " (did you mean /uav1/setpoints?)"


def test_echo_of_a_topic_with_only_subscriptions_says_so(ns, own_domain):
    from zenoh_robot import Node, msgs

    with Node("listener", namespace=ns) as node:
        node.create_subscription(msgs.String, "heard", lambda m: None)
        r = cli("topic", "echo", f"/{ns}/heard", "--duration", "2")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r
    assert f"waiting for /{ns}/heard... (only subscriptions so far)" in r.stderr, r.stderr
    assert f"did you mean /{ns}/heard" not in r.stderr, r.stderr
