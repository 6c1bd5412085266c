"""Node parameters: declare/get/set with types, refusing callbacks, overrides, -p parsing, remote CLI."""
from __future__ import annotations

import threading

import pytest
from cli_helpers import CLI_ARGS
from conftest import python_proc, wait_ready

from zenoh_robot import History, Node, QoSError, QoSProfile, Reliability
from zenoh_robot.parameters import (
    InvalidParameterTypeError,
    InvalidParameterValueError,
    Parameter,
    ParameterAlreadyDeclaredError,
    ParameterClient,
    ParameterNotDeclaredError,
    ParameterType,
    SetParametersResult,
    current_caller,
    default_client_id,
    format_param_value,
    parse_param_args,
    qos_from_parameters,
)


@pytest.fixture
def node(ns):
    with Node("params", namespace=ns) as n:
        yield n


@pytest.mark.fast
def test_declare_and_get(node):
    p = node.declare_parameter("depth", 10, "queue depth")
    assert (p.name, p.value, p.type_) == ("depth", 10, ParameterType.INTEGER)
    node.declare_parameter("gain", 0.5)
    node.declare_parameter("enabled", True)
    node.declare_parameter("frames", ["base", "cam"])
    assert node.has_parameter("gain") and not node.has_parameter("nope")
    assert node.get_parameter("gain").type_ is ParameterType.DOUBLE
    assert node.get_parameter("enabled").type_ is ParameterType.BOOL
    assert node.get_parameter("frames").type_ is ParameterType.STRING_ARRAY
    assert node.get_parameter_value("frames") == ["base", "cam"]
    assert node.describe_parameter("depth").description == "queue depth"
    assert node.list_parameters() == ["depth", "enabled", "frames", "gain"]
    with pytest.raises(ParameterNotDeclaredError, match="'nope' is not declared"):
        node.get_parameter("nope")
    with pytest.raises(ParameterAlreadyDeclaredError):
        node.declare_parameter("depth", 3)
    declared = node.declare_parameters("cam", [("fps", 30), ("width", 320, "pixels")])
    assert [p.name for p in declared] == ["cam.fps", "cam.width"]
    assert node.list_parameters(["cam"]) == ["cam.fps", "cam.width"]
    with pytest.raises(InvalidParameterTypeError, match="default value or type_"):
        node.declare_parameter("untyped")


@pytest.mark.fast
def test_set_with_type_checks(node):
    node.declare_parameter("depth", 10)
    node.declare_parameter("gain", 0.5)
    node.declare_parameter("ro", "fixed", read_only=True)
    results = node.set_parameters([Parameter("depth", 3), Parameter("depth", "x"), Parameter("gain", 2),
                                   Parameter("ro", "other"), Parameter("missing", 1),
                                   Parameter("depth", True)])
    assert [r.successful for r in results] == [True, False, True, False, False, False]
    assert "expected integer, got str 'x'" in results[1].reason
    assert "read-only" in results[3].reason
    assert "not declared" in results[4].reason
    assert node.get_parameter_value("depth") == 3
    gain = node.get_parameter("gain")          # int -> float is the one conversion allowed
    assert gain.value == 2.0 and isinstance(gain.value, float)
    assert node.get_parameter_value("ro") == "fixed"
    # rclpy's constructor form works too
    assert node.set_parameters([Parameter("depth", Parameter.Type.INTEGER, 7)])[0].successful
    assert node.get_parameter_value("depth") == 7


@pytest.mark.fast
def test_on_set_callback_may_refuse(node):
    node.declare_parameter("gain", 0.5)
    seen = []

    def check(params):
        seen.extend(p.name for p in params)
        for p in params:
            if p.name == "gain" and p.value > 1.0:
                return SetParametersResult(False, "gain must be <= 1.0")
        return SetParametersResult(True)

    node.add_on_set_parameters_callback(check)
    ok, refused = node.set_parameters([Parameter("gain", 0.9), Parameter("gain", 1.5)])
    assert ok.successful
    assert not refused.successful and refused.reason == "gain must be <= 1.0"
    assert node.get_parameter_value("gain") == 0.9
    assert seen == ["gain", "gain"]
    # all or nothing
    node.declare_parameter("depth", 1)
    result = node.set_parameters_atomically([Parameter("depth", 5), Parameter("gain", 3.0)])
    assert not result.successful and node.get_parameter_value("depth") == 1
    # a callback that raises refuses with its text
    node.add_on_set_parameters_callback(lambda ps: 1 / 0)
    r = node.set_parameters([Parameter("depth", 2)])[0]
    assert not r.successful and "ZeroDivisionError" in r.reason


@pytest.mark.fast
def test_overrides_apply_at_declare_time(ns):
    overrides = parse_param_args(["-p", "depth:=3", "-p", "gain:=1", "--param", "mode:=best_effort",
                                  "-p", "flag:=true", "-p", "l:=[1, 2.5]", "name:=", "-p", "text:='5'"])
    assert overrides == {"depth": 3, "gain": 1, "mode": "best_effort", "flag": True, "l": [1, 2.5],
                         "name": "", "text": "5"}
    with Node("over", namespace=ns, parameter_overrides=overrides) as node:
        assert node.declare_parameter("depth", 10).value == 3
        gain = node.declare_parameter("gain", 0.5)
        assert gain.value == 1.0 and gain.type_ is ParameterType.DOUBLE
        assert node.declare_parameter("flag", False).value is True
        assert node.declare_parameter("l", [0.0]).value == [1.0, 2.5]
        assert node.declare_parameter("untouched", "x").value == "x"
        with pytest.raises(InvalidParameterTypeError, match=r"'mode' \(override\).*expected integer"):
            node.declare_parameter("mode", 1)
        node.add_on_set_parameters_callback(lambda ps: SetParametersResult(False, "no"))
        with pytest.raises(InvalidParameterValueError, match="refused: no"):
            node.declare_parameter("text", "a")
    with pytest.raises(InvalidParameterValueError, match="expected NAME:=VALUE"):
        parse_param_args(["-p", "depth=3"])
    for value in ["5", "true", "", "a: b", "plain", [1, 2], 0.5, False, ["x", "y z"]]:
        assert parse_param_args([f"p:={format_param_value(value)}"]) == {"p": value}


def test_qos_from_parameters(ns):
    base = QoSProfile(reliability=Reliability.RELIABLE, depth=10)
    with Node("qos", namespace=ns, parameter_overrides={"reliability": "best_effort", "depth": 1}) as node:
        qos = qos_from_parameters(node, base)
        assert qos.reliability is Reliability.BEST_EFFORT and qos.depth == 1
        assert qos.history is History.KEEP_LAST
        assert node.list_parameters() == ["depth", "history", "reliability"]
    with Node("qos2", namespace=ns, parameter_overrides={"sensor.reliability": "sometimes"}) as node:
        with pytest.raises(QoSError, match="sensor.reliability"):
            qos_from_parameters(node, base, prefix="sensor")


def _cli(*args: str) -> tuple[int, str]:
    proc = python_proc(*CLI_ARGS, "param", *args)
    out, _ = proc.communicate(timeout=30)
    return proc.returncode, out


def test_remote_param_cli(ns):
    node = python_proc("tests/procs/svc_param_node.py", "--ns", ns, "-p", "depth:=4")
    target = f"/{ns}/pnode"
    try:
        assert wait_ready(node)
        rc, out = _cli("list", target)
        assert rc == 0, out
        assert out.split() == ["depth", "frames", "gain", "mode"]
        rc, out = _cli("get", target, "depth")
        assert (rc, out.strip()) == (0, "Integer value is: 4")     # the -p override
        rc, out = _cli("set", target, "gain", "0.75")
        assert (rc, out.strip()) == (0, "Set parameter successful")
        rc, out = _cli("get", target, "gain")
        assert out.strip() == "Double value is: 0.75"
        rc, out = _cli("set", target, "gain", "3")
        assert rc == 1 and "gain must be <= 1.0" in out
        rc, out = _cli("set", target, "depth", "lots")
        assert rc == 1 and "expected integer, got str 'lots'" in out
        rc, out = _cli("get", target, "nope")
        assert rc == 1 and "has no parameter 'nope'" in out
        rc, out = _cli("--timeout", "1", "list", f"/{ns}/ghost")
        assert rc == 1 and f"node /{ns}/ghost not found" in out
        assert len(out.strip().splitlines()) == 1, out
    finally:
        node.terminate()
        node.wait(timeout=10)


@pytest.mark.fast
def test_a_write_guard_judges_each_remote_request_by_its_caller(ns):
    """Node.set_parameter_write_guard over real sessions: the caller's client_id reaches the guard
    and the on-set callbacks; a refusal covers the whole request; local sets and guardless nodes
    keep rclpy's behaviour; a guard that breaks refuses."""
    with Node("keeper", namespace=ns) as server, Node("asker", namespace=ns) as asker:
        server.declare_parameter("limit", 1.0)
        server.declare_parameter("free", 1)
        asked: list[tuple[list[str], str]] = []
        callers: list[str] = []

        def guard(names: list[str], caller: str) -> str:
            asked.append((names, caller))
            return "" if caller == "boss" or names == ["free"] else f"limit: only boss, not {caller}"

        server.add_on_set_parameters_callback(lambda ps: callers.append(current_caller()) or SetParametersResult(True))
        stop = threading.Event()
        spinner = threading.Thread(target=lambda: [server.spin_once(0.05) for _ in iter(stop.is_set, True)])
        spinner.start()
        try:
            boss = ParameterClient(asker, f"/{ns}/keeper", timeout=3.0, client_id="boss")
            other = ParameterClient(asker, f"/{ns}/keeper", timeout=3.0, client_id="other")
            assert boss.wait_for_node(5.0)
            assert other.set([Parameter("limit", 2.0)])[0].successful   # no guard: rclpy's behaviour
            assert callers == ["other"]
            server.set_parameter_write_guard(guard)
            results = other.set([Parameter("free", 2), Parameter("limit", 3.0)])
            assert [r.successful for r in results] == [False, False]
            assert all(r.reason == "limit: only boss, not other" for r in results)
            assert asked[-1] == (["free", "limit"], "other")
            assert server.get_parameter_value("limit") == 2.0 and server.get_parameter_value("free") == 1
            assert other.set([Parameter("free", 5)])[0].successful
            assert boss.set([Parameter("limit", 4.0)])[0].successful and server.get_parameter_value("limit") == 4.0
            assert callers[-2:] == ["other", "boss"]
            assert server.set_parameters([Parameter("limit", 0.5)])[0].successful   # local: no guard, no caller
            assert callers[-1] == "" and current_caller() == ""
            server.set_parameter_write_guard(lambda names, caller: 1 / 0)
            (r,) = boss.set([Parameter("limit", 9.0)])
            assert not r.successful and "write guard raised ZeroDivisionError" in r.reason
            assert server.get_parameter_value("limit") == 0.5
        finally:
            stop.set()
            spinner.join(5)
    # Without client_id the client sends the id a GCS uses by default (user@host).
    assert ParameterClient.__init__.__defaults__ == (3.0, None)
    assert "@" in default_client_id() and len(default_client_id()) <= 64
