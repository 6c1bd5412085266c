"""The README's first example and examples/ run as a user runs them (issue #39: every example executed):
the README's Python block hears its own setpoints, the talker/listener pair talks, the watchdog sees the
talker, and each stops on Ctrl-C without a traceback."""
from __future__ import annotations

import re
import signal
import subprocess
from pathlib import Path

from conftest import Lines, fresh_domain, kill_process, python_proc

ROOT = Path(__file__).resolve().parents[2]


def _first_python_block(text: str, after: str) -> str:
    section = text[text.index(after):]
    start = section.index("```python\n") + len("```python\n")
    return section[start:section.index("```", start)]


def _run(script: str, *args: str, env: dict[str, str]) -> subprocess.Popen:
    """``python script args`` as from a terminal: a test run started in the background passes an ignored
    SIGINT on to its children, where Ctrl-C would then never become KeyboardInterrupt."""
    boot = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')")
    return python_proc("-c", boot, script, *args, env=env)


def _stop(proc: subprocess.Popen, lines: Lines) -> str:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        kill_process(proc)
    return lines.text()


def test_the_readme_first_example_hears_its_own_setpoints(tmp_path: Path) -> None:
    script = tmp_path / "first.py"
    script.write_text(_first_python_block((ROOT / "README.md").read_text(), "## A first example"))
    proc = _run(str(script), env={"ZR_DOMAIN": str(fresh_domain())})
    lines = Lines(proc)
    try:
        assert lines.wait_for(r"^1\.0 \d+\.\d ms old$", 30), lines.text()[-2000:]
    finally:
        out = _stop(proc, lines)
    assert "Traceback" not in out, out[-2000:]


def test_talker_listener_and_watchdog_examples() -> None:
    ns = f"ex{fresh_domain()}"
    env = {"ZR_DOMAIN": str(fresh_domain())}
    procs = {name: _run(f"examples/{name}.py", "--ns", ns, env=env)
             for name in ("listener", "watchdog", "talker")}
    lines = {name: Lines(p) for name, p in procs.items()}
    try:
        assert lines["listener"].wait_for(r"\S", 30), lines["listener"].text()[-2000:]
        assert lines["watchdog"].wait_for(r"matched publishers: 1", 30), lines["watchdog"].text()[-2000:]
    finally:
        outs = {name: _stop(p, lines[name]) for name, p in procs.items()}
    for name, out in outs.items():
        assert "Traceback" not in out, f"{name}: {out[-2000:]}"
    assert re.search(r"\d", outs["listener"]), outs["listener"]
