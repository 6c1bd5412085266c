"""`zenoh-robot node|service|param` verbs of the second CLI half, against a live node in another process.

One talker process (conftest's ``talker`` fixture running TALKER) serves the module:
a publisher, a subscription, a service, and parameters,
one read-only, with an on-set callback that agrees to delete only ``scratch``.
"""
from __future__ import annotations

import subprocess
import threading

from cli_helpers import cli

from zenoh_robot import Node
from zenoh_robot.parameters import ParameterClient, ParameterType, SetParametersResult
from zenoh_robot.parameters.types import Parameter

TALKER = r"""
import sys
from zenoh_robot import Node, msgs, qos
from zenoh_robot.parameters import SetParametersResult

def on_set(params):
    # deletion (type NOT_SET, value None) agreed for `scratch` only
    ok = all(p.value is not None or p.name == "scratch" for p in params)
    return SetParametersResult(ok, "" if ok else "only scratch may go")

ns = sys.argv[1]
with Node("talker", namespace=ns) as n:
    n.declare_parameter("rate", 10.0)
    n.declare_parameter("mode", "auto")
    n.declare_parameter("gains.kp", 1.0)
    n.declare_parameter("scratch", 1)
    n.declare_parameter("fixed", 3, read_only=True)
    n.add_on_set_parameters_callback(on_set)
    chatter = n.create_publisher(msgs.String, "chatter", qos.SENSOR)
    n.create_subscription(msgs.Setpoint, "setpoint", lambda m: None, 10)
    n.create_service("echo", msgs.Setpoint, msgs.Setpoint, lambda r: r)
    print("ready", flush=True)
    while True:
        chatter.publish(msgs.String("x"))
        n.spin(0.1)
"""


def _one_error(out: subprocess.CompletedProcess) -> str:
    assert out.returncode == 1, (out.stdout, out.stderr)
    lines = out.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    return lines[0]


# -- node -------------------------------------------------------------------------------------
def test_node_list_shows_the_talker_and_hides_the_cli(talker):
    out = cli("node", "list")
    assert out.returncode == 0, out.stderr
    names = out.stdout.splitlines()
    assert f"/{talker}/talker" in names
    assert not [n for n in names if "/_zr_" in n], names
    count = cli("node", "list", "--count-nodes")
    assert count.returncode == 0 and int(count.stdout) >= 1, count


def test_node_info_lists_endpoints_services_and_parameters(talker):
    out = cli("node", "info", f"/{talker}/talker")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == f"/{talker}/talker"
    sections = {line.strip(): i for i, line in enumerate(lines) if line.startswith("  ") and line.endswith(":")}
    subs, pubs, srvs = sections["Subscribers:"], sections["Publishers:"], sections["Service Servers:"]
    assert lines[subs + 1] == f"    /{talker}/setpoint: zenoh_robot/Setpoint"
    assert lines[pubs + 1] == f"    /{talker}/chatter: std_msgs/String"
    served = lines[srvs + 1:srvs + 6]
    assert f"    /{talker}/echo: zenoh_robot/Setpoint -> zenoh_robot/Setpoint" in served
    assert f"    /{talker}/talker/get_parameters: zenoh_robot/GetParameters_Request -> " \
           "zenoh_robot/GetParameters_Response" in served
    assert "  Parameters: 5" in lines


def test_node_info_of_a_missing_node_suggests_the_near_one(talker):
    assert f"did you mean /{talker}/talker?" in _one_error(cli("node", "info", f"/{talker}/talke", "--timeout", "1"))


# -- service ----------------------------------------------------------------------------------
def test_service_type_and_find(talker):
    out = cli("service", "type", f"/{talker}/talker/set_parameters")
    assert out.returncode == 0 and out.stdout == "zenoh_robot/SetParameters\n", out
    out = cli("service", "type", f"/{talker}/echo")
    assert out.returncode == 0 and out.stdout == "zenoh_robot/Setpoint -> zenoh_robot/Setpoint\n", out
    out = cli("service", "find", "SetParameters")
    assert out.returncode == 0, out.stderr
    assert f"/{talker}/talker/set_parameters" in out.stdout.splitlines()
    assert f"/{talker}/echo" not in out.stdout
    out = cli("service", "find", "zenoh_robot/Setpoint")
    assert f"/{talker}/echo" in out.stdout.splitlines(), out
    assert "did you mean" in _one_error(cli("service", "type", f"/{talker}/ecko", "--timeout", "1"))


def test_service_call_coerces_like_topic_pub(talker):
    out = cli("service", "call", f"/{talker}/echo", "{x: 5, is_velocity: true}")
    assert out.returncode == 0, out.stderr
    assert "x: 5.0" in out.stdout.splitlines() and "is_velocity: true" in out.stdout, out.stdout   # int -> float64
    err = _one_error(cli("service", "call", f"/{talker}/echo", "{x: fast}"))
    assert "Setpoint.x: expected float64, got str 'fast'" in err
    assert "has no field(s) ['speed']" in _one_error(cli("service", "call", f"/{talker}/echo", "{speed: 1}"))
    assert "must be a YAML mapping" in _one_error(cli("service", "call", f"/{talker}/echo", "[1]"))


# -- param load / delete ----------------------------------------------------------------------
def test_param_load_ros2_file_then_dump_round_trips(talker, tmp_path):
    node = f"/{talker}/talker"
    ros2 = tmp_path / "params.yaml"
    ros2.write_text(f"{node}:\n  ros__parameters:\n    rate: 20\n    mode: 5\n    gains:\n      kp: 2.5\n"
                    "/**:\n  ros__parameters:\n    scratch: 7\n")
    out = cli("param", "load", node, str(ros2))
    assert out.returncode == 0, out.stderr
    assert sorted(out.stdout.splitlines()) == sorted(f"Set parameter {n} successful"
                                                     for n in ("rate", "mode", "gains.kp", "scratch"))
    dump = cli("param", "dump", node)
    assert dump.returncode == 0, dump.stderr
    for line in ("    rate: 20.0", "    mode: '5'", "    gains.kp: 2.5", "    scratch: 7", "    fixed: 3"):
        assert line in dump.stdout.splitlines(), dump.stdout
    dumped = tmp_path / "dump.yaml"
    dumped.write_text(dump.stdout.replace("rate: 20.0", "rate: 30.0"))
    out = cli("param", "load", node, str(dumped))      # the read-only one, unchanged, is no failure
    assert out.returncode == 0, (out.stdout, out.stderr)
    assert cli("param", "get", node, "rate").stdout == "Double value is: 30.0\n"


def test_param_load_reports_failures_and_exits_non_zero(talker, tmp_path):
    node = f"/{talker}/talker"
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"{node}:\n  ros__parameters:\n    rate: fast\n    nope: 1\n")
    out = cli("param", "load", node, str(bad))
    assert out.returncode == 1, out
    assert "Set parameter rate failed" in out.stdout and "has no parameter 'nope'" in out.stdout
    assert out.stderr.strip().endswith(f"2 of 2 parameters from {bad} not set"), out.stderr
    other = tmp_path / "other.yaml"
    other.write_text("/elsewhere:\n  ros__parameters:\n    rate: 1\n")
    assert f"no section for {node}" in _one_error(cli("param", "load", node, str(other)))


def test_param_delete_needs_the_nodes_consent(talker):
    node = f"/{talker}/talker"
    assert "only scratch may go" in _one_error(cli("param", "delete", node, "rate"))
    assert "read-only" in _one_error(cli("param", "delete", node, "fixed"))
    out = cli("param", "delete", node, "scratch")
    assert out.returncode == 0 and out.stdout == "Deleted parameter successfully\n", out
    assert "  scratch" not in cli("param", "list", node).stdout.splitlines()
    assert "not declared" in _one_error(cli("param", "delete", node, "scratch"))


def test_remote_delete_without_an_on_set_callback_is_refused(ns):
    """The library rule behind `param delete`: a node that never agreed keeps its parameter."""
    with Node("keeper", namespace=ns) as server, Node("asker", namespace=ns) as asker:
        server.declare_parameter("rate", 10.0)
        server.declare_parameter("tmp", 1)
        stop = threading.Event()
        spinner = threading.Thread(target=lambda: [server.spin_once(0.05) for _ in iter(stop.is_set, True)])
        spinner.start()
        try:
            client = ParameterClient(asker, f"/{ns}/keeper", timeout=3.0)
            assert client.wait_for_node(5.0)
            (res,) = client.set([Parameter("rate", ParameterType.NOT_SET)])
            assert not res.successful and "no remote deletion" in res.reason
            assert server.has_parameter("rate")
            server.add_on_set_parameters_callback(lambda ps: SetParametersResult(True))
            (res,) = client.set([Parameter("tmp", ParameterType.NOT_SET)])
            assert res.successful, res.reason
            assert not server.has_parameter("tmp") and server.has_parameter("rate")
        finally:
            stop.set()
            spinner.join(5)
