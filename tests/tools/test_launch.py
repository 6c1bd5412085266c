"""Launch files: validation, substitutions, prefixed output, stopping everything together."""
from __future__ import annotations

import io
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from cli_helpers import CLI_ARGS
from conftest import ROOT, python_proc, wait_for

from zenoh_robot.tools.launch import LaunchError, LaunchRunner, ProcessSpec, load_launch

ZR = [sys.executable, *CLI_ARGS]
CHILD = str(ROOT / "tests" / "procs" / "launch_child.py")


def write(tmp_path: Path, text: str, name: str = "test.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:   # a zombie is dead for our purpose
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except OSError:
        return False


def test_required_failure_stops_the_rest_and_names_it(tmp_path):
    path = write(tmp_path, f"""
        processes:
          - name: steady
            cmd: ["$(python)", "{CHILD}"]
          - name: flaky
            cmd: ["$(python)", "{CHILD}", "--fail-after", "0.8", "--code", "7"]
            delay: 0.2
    """)
    proc = python_proc(*CLI_ARGS, "launch", str(path), "--sigint-timeout", "3")
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 1, out
    assert "required process 'flaky' failed (exit code 7); stopping everything" in out
    lines = out.splitlines()
    assert any(re.match(r"^\[steady\] +tick \d+$", line) for line in lines), out
    assert any(re.match(r"^\[flaky\] +failing now$", line) for line in lines), out
    assert any(re.match(r"^\[steady\] +interrupted, bye$", line) for line in lines), out
    steady_pid = int(re.search(r"^\[steady\] +pid (\d+)", out, re.M).group(1))
    assert not alive(steady_pid)


def test_sigint_stops_everything_cleanly_including_grandchildren(tmp_path):
    path = write(tmp_path, f"""
        processes:
          - name: a
            cmd: ["$(python)", "{CHILD}", "--grandchild"]
          - name: b
            cmd: ["$(python)", "{CHILD}"]
    """)
    proc = python_proc(*CLI_ARGS, "launch", str(path))
    seen: list[str] = []
    start = time.monotonic()
    deadline = start + 30
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        seen.append(line)
        text = "".join(seen)
        if not line or "grandchild pid" in text and re.search(r"^\[b\] +tick", text, re.M):
            break   # (no line: the launch ended)
    text = "".join(seen)
    found = re.search(r"grandchild pid (\d+)", text)
    assert found, f"no grandchild in {time.monotonic() - start:.0f} s: {text}"
    grandchild = int(found.group(1))
    pids = [int(p) for p in re.findall(r"^\[[ab]\] +pid (\d+)", text, re.M)]
    assert len(pids) == 2 and alive(grandchild)
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, text + rest
    assert "SIGINT received; stopping" in rest
    assert "process 'a' stopped" in rest and "process 'b' stopped" in rest
    assert wait_for(lambda: not any(alive(p) for p in [*pids, grandchild]), timeout=5)


def test_escalates_to_sigterm_and_keeps_optional_exits(tmp_path):
    out = io.StringIO()
    runner = LaunchRunner([
        ProcessSpec("stubborn", [sys.executable, CHILD, "--ignore-sigint"]),
        ProcessSpec("oneshot", [sys.executable, "-c", "print('done')"], required=False),
    ], output=out, color=False, sigint_timeout=0.5, sigterm_timeout=3.0)
    t0 = time.monotonic()
    code = runner.run(duration=1.5, handle_signals=False)
    text = out.getvalue()
    assert code == 0, text
    assert time.monotonic() - t0 < 15
    assert "process 'oneshot' exited (exit code 0)" in text       # optional: the launch went on
    assert "duration of 1.5 s reached; stopping" in text
    assert "sending SIGTERM to 'stubborn'" in text
    assert runner.returncodes["stubborn"] == -signal.SIGTERM
    assert runner.failed is None


def test_respawn(tmp_path):
    out = io.StringIO()
    runner = LaunchRunner([ProcessSpec("blip", [sys.executable, "-c", "print('hi')"], respawn=True,
                                       respawn_delay=0.1)], output=out, color=False)
    assert runner.run(duration=2.5, handle_signals=False) == 0
    assert len(re.findall(r"^\[blip\] +hi$", out.getvalue(), re.M)) >= 2


@pytest.mark.fast
def test_substitutions_params_and_includes(tmp_path, monkeypatch):
    monkeypatch.setenv("ZR_TEST_LEVEL", "warn")
    write(tmp_path, """
        args:
          ns: {description: drone namespace}
        processes:
          - name: sim_$(arg ns)
            exec: sim --id $(arg ns)
    """, "sim.yaml")
    path = write(tmp_path, """
        args:
          ns: uav1
          depth: 5
        include:
          - file: sim.yaml
            args: {ns: $(arg ns)}
        processes:
          - name: companion
            exec: zenoh-robot companion --id $(arg ns)
            args: --verbose
            params: {depth: $(arg depth), reliability: best_effort, frames: [a, b], label: "5", enabled: true}
            env: {RUST_LOG: $(env ZR_TEST_LEVEL), MISSING: $(env ZR_NOT_SET fallback)}
          - name: mod
            module: companion
            required: false
            delay: 2
    """)
    desc = load_launch(path, {"ns": "uav7", "depth": "3"})
    sim, comp, mod = desc.processes
    assert sim.name == "sim_uav7"
    assert sim.argv == [*ZR, "sim", "--id", "uav7"]
    assert comp.argv == [*ZR, "companion", "--id", "uav7",
                         "--verbose", "-p", "depth:=3", "-p", "reliability:=best_effort",
                         "-p", "frames:=[a, b]", "-p", "label:='5'", "-p", "enabled:=true"]
    assert comp.env == {"RUST_LOG": "warn", "MISSING": "fallback"}
    assert mod.argv == [sys.executable, "-m", "companion"] and not mod.required and mod.delay == 2
    # the -p strings parse back to the values the file meant
    from zenoh_robot.parameters import parse_param_args
    assert parse_param_args(comp.argv[comp.argv.index("-p"):]) == {
        "depth": 3, "reliability": "best_effort", "frames": ["a", "b"], "label": "5", "enabled": True}


@pytest.mark.parametrize("body, message", [
    ("processes:\n  - name: x\n    comand: [ls]\n", "unknown key(s) comand"),
    ("processes:\n  - name: x\n    args: [a]\n", "needs exactly one of cmd, exec, module"),
    ("processes:\n  - name: x\n    cmd: [ls]\n    module: m\n", "(has cmd, module)"),
    ("processes:\n  - cmd: [ls]\n", "needs a name"),
    ("proceses: []\n", "unknown key(s) proceses"),
    ("processes:\n  - {name: x, cmd: [ls]}\n  - {name: x, cmd: [ls]}\n", "two processes are named 'x'"),
    ("processes:\n  - {name: x, cmd: [ls], delay: soon}\n", "'soon' is not a number"),
    ("processes:\n  - {name: x, cmd: [\"$(arg nope)\"]}\n", "unknown launch argument $(arg nope)"),
    ("args: {need: {description: d}}\nprocesses:\n  - {name: x, cmd: [ls]}\n", "pass need:=VALUE"),
    ("processes: [\n", "not valid YAML"),
])
@pytest.mark.fast
def test_validation_errors_are_clear(tmp_path, body, message):
    path = write(tmp_path, body)
    with pytest.raises(LaunchError) as err:
        load_launch(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def test_cli_reports_bad_files_in_one_line(tmp_path):
    path = write(tmp_path, "processes:\n  - name: x\n    cmd: [ls]\n")
    proc = python_proc(*CLI_ARGS, "launch", str(path), "bogus:=1")
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 1
    assert out.strip().splitlines() == [
        f"zenoh-robot launch: {path}: unknown launch argument(s) bogus; declared: none"]


@pytest.mark.fast
@pytest.mark.parametrize("name", ["demo", "gcs_reliable", "gcs_best_effort", "drone_reliable", "drone_best_effort"])
def test_shipped_launch_files_validate(name: str) -> None:
    from zenoh_robot.tools.launch import load_launch
    path = Path(__file__).resolve().parents[2] / "configs" / "launch" / f"{name}.yaml"
    specs = load_launch(path).processes
    assert specs and all(s.argv[1] == "-m" for s in specs), specs


STOPPER = r"""
import signal, sys, time
name = sys.argv[1]
def stop(*_):
    print(f"{name} got SIGINT at {time.monotonic():.6f}", flush=True)
    time.sleep(0.3)   # a dependent's orderly stop takes a moment (a companion commanding HOLD)
    print(f"{name} done at {time.monotonic():.6f}", flush=True)
    sys.exit(0)
signal.signal(signal.SIGINT, stop)
print(f"{name} up", flush=True)
while True:
    time.sleep(0.05)
"""


def test_stop_goes_in_reverse_dependency_order(tmp_path):
    """sim <- companion <- gcs: Ctrl-C stops gcs first, then companion, then sim; each signalled
    only once the one depending on it has exited."""
    script = tmp_path / "stopper.py"
    script.write_text(STOPPER)
    path = write(tmp_path, f"""
        processes:
          - name: sim
            cmd: ["$(python)", "{script}", sim]
          - name: companion
            cmd: ["$(python)", "{script}", companion]
            depends_on: [sim]
          - name: gcs
            cmd: ["$(python)", "{script}", gcs]
            depends_on: [companion]
    """)
    proc = python_proc(*CLI_ARGS, "launch", str(path))
    seen: list[str] = []
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and sum(" up" in line for line in seen) < 3:
        seen.append(proc.stdout.readline())
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=30)
    text = "".join(seen) + rest
    assert proc.returncode == 0, text
    t = {m[1] + m[2]: float(m[3]) for m in re.finditer(r"(\w+) (got SIGINT|done) at ([\d.]+)", text)}
    assert t["gcsdone"] <= t["companiongot SIGINT"], text
    assert t["companiondone"] <= t["simgot SIGINT"], text


@pytest.mark.fast
def test_stop_order_defaults_to_reverse_declaration_and_refuses_cycles(tmp_path):
    from zenoh_robot.tools.launch import stop_order
    specs = [ProcessSpec("sim", ["x"]), ProcessSpec("companion", ["x"]), ProcessSpec("gcs", ["x"])]
    assert stop_order(specs) == [["gcs"], ["companion"], ["sim"]]
    specs = [ProcessSpec("a", ["x"], depends_on=["b"]), ProcessSpec("b", ["x"], depends_on=["a"])]
    with pytest.raises(LaunchError, match="cycle"):
        stop_order(specs)


def test_cli_takes_launch_arguments_after_show(tmp_path):
    r = subprocess.run([*ZR, "launch", str(ROOT / "configs/launch/demo.yaml"), "--show", "duration:=20"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "--duration 20" in r.stdout


@pytest.mark.parametrize("cmd", ["[false]", "[null]", "[yes, x]"])
def test_yaml_values_in_a_command_are_named(tmp_path, cmd):
    path = write(tmp_path, f"""
        processes:
          - name: b
            cmd: {cmd}
    """)
    r = subprocess.run([*ZR, "launch", str(path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "is a YAML" in r.stderr and "quote it" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
