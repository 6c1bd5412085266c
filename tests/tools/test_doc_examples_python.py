"""The Python examples of README.md and docs/ run as a user runs them (issue #39: every example executed),
and examples/ (talker, listener, watchdog) too.

A ```python block right after ``<!-- doc-test: python "REGEX" -->`` is run as a script in a Zenoh domain of
its own: it must print a line matching REGEX (an example that spins is then stopped with Ctrl-C, as a user
would; ``python ends "REGEX"``: one that ends by itself must then exit 0 unaided), and never print a
traceback. ``<!-- doc-test: python -->`` (no REGEX): it must run for a few seconds without a traceback
(``python ends``: end by itself with exit 0). Fragments (``...``, names defined elsewhere) are marked
``fragment``: tests/tools/test_doc_blocks.py compiles them and resolves their imports.
"""
from __future__ import annotations

import re
import signal
import subprocess
from pathlib import Path

import pytest
from conftest import Lines, fresh_domain, kill_process, python_proc
from doc_helpers import all_blocks

PYTHON = re.compile(r'python(?P<ends>\s+ends)?(?:\s+"(?P<expect>[^"]*)")?')
QUIET_S = 3.0     # an example that prints nothing by design runs this long, then gets Ctrl-C


def marked_blocks() -> list[tuple[str, str | None, bool, str]]:
    """(where, expected line or None, whether it ends by itself, code) of every marked Python block."""
    out: list[tuple[str, str | None, bool, str]] = []
    for block in all_blocks():
        m = PYTHON.fullmatch(block.kind or "") if block.lang == "python" else None
        if m:
            out.append((block.where, m["expect"], bool(m["ends"]), "\n".join(block.lines) + "\n"))
    return out


def _run(script: str, *args: str, env: dict[str, str]) -> subprocess.Popen:
    """``python script args`` as from a terminal: a test run started in the background passes an ignored
    SIGINT on to its children, where Ctrl-C would then never become KeyboardInterrupt."""
    boot = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')")
    return python_proc("-c", boot, script, *args, env=env)


def _stop(proc: subprocess.Popen, lines: Lines) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        kill_process(proc)
    return lines.text()


def test_the_docs_mark_their_runnable_examples() -> None:
    where = [w for w, _, _, _ in marked_blocks()]
    assert any(w.startswith("README.md") for w in where) and any(w.startswith("docs/guide.md") for w in where)


@pytest.mark.parametrize(("where", "expect", "ends", "code"), marked_blocks(),
                         ids=[w for w, _, _, _ in marked_blocks()])
def test_a_marked_doc_example_runs(where: str, expect: str | None, ends: bool, code: str, tmp_path: Path) -> None:
    script = tmp_path / "example.py"
    script.write_text(code)
    proc = _run(str(script), env={"ZR_DOMAIN": str(fresh_domain())})
    lines = Lines(proc)
    try:
        if expect is not None:
            assert lines.wait_for(expect, 30), f"{where}: no line matching {expect!r}:\n{lines.text()[-2000:]}"
            if ends:     # it closes its sessions and exits by itself: no Ctrl-C in the middle of that
                assert proc.wait(timeout=30) == 0, f"{where}: exit {proc.returncode}\n{lines.text()[-2000:]}"
        elif ends:
            assert proc.wait(timeout=30) == 0, f"{where}: exit {proc.returncode}\n{lines.text()[-2000:]}"
        else:
            try:
                proc.wait(timeout=QUIET_S)
            except subprocess.TimeoutExpired:
                pass
    finally:
        out = _stop(proc, lines)
    assert "Traceback" not in out, f"{where}:\n{out[-2000:]}"
    assert proc.returncode in (0, -signal.SIGINT, 130), f"{where}: exit {proc.returncode}\n{out[-2000:]}"


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
