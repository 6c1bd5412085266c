"""docs/cli.md's examples run as written (issue #39): a doc cannot drift from the code again.

A code block right after ``<!-- doc-test: companion uav1 -->`` is run line by line against a companion
(``--id uav1``, the built-in simulator) in a domain of its own: each command must exit 0 with no
traceback. A command marked ``# until Ctrl-C`` runs until it has printed its first line, then gets
Ctrl-C and must end with exit 0, as a user stopping it would see.
"""
from __future__ import annotations

import re
import shlex
import signal
import subprocess
from collections.abc import Iterator

import pytest
from cli_helpers import CLI_ARGS, cli
from conftest import Lines, fresh_domain, kill_process, python_proc
from doc_helpers import ROOT, blocks

DOC = ROOT / "docs" / "cli.md"
UNTIL_CTRL_C = "# until Ctrl-C"


def doc_commands(needs: str) -> list[str]:
    """The command lines of DOC's blocks marked ``doc-test: <needs>``, continuation lines joined."""
    out: list[str] = []
    for block in blocks(DOC):
        if block.kind != needs:
            continue
        joined = " ".join(line.strip() for line in block.lines if line.strip()).replace("\\ ", "")
        out += [c.strip() for c in re.split(r"(?=\bzenoh-robot )", joined) if c.strip()]
    return out


COMMANDS = doc_commands("companion uav1")


def test_the_marked_examples_cover_the_everyday_commands():
    verbs = {shlex.split(c, comments=True)[1] for c in COMMANDS}
    assert {"topic", "node", "service", "interface", "param"} <= verbs, COMMANDS


def _sigint_default() -> None:
    # A test run in the background (`pytest &`) hands its children SIGINT ignored; these are stopped with it.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(scope="module")
def companion() -> Iterator[Lines]:
    env = pytest.MonkeyPatch()
    env.setenv("ZR_DOMAIN", str(fresh_domain()))
    proc = python_proc("-m", "companion", "--id", "uav1", "--px4", "sim", "--camera", "none",
                       preexec_fn=_sigint_default)
    try:
        out = Lines(proc)
        assert out.wait_for("companion uav1: PX4 at", 60.0), out.text()
        yield out
    finally:
        proc.send_signal(signal.SIGINT)     # as a user stops it; its output stays with Lines' reader
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            pass
        kill_process(proc)
        env.undo()


@pytest.mark.parametrize("command", COMMANDS, ids=[" ".join(shlex.split(c, comments=True)[1:4]) for c in COMMANDS])
def test_a_doc_example_runs_as_written(companion, command):
    argv = shlex.split(command, comments=True)
    assert argv[0] == "zenoh-robot", command
    if UNTIL_CTRL_C in command:
        proc = python_proc(*CLI_ARGS, *argv[1:], preexec_fn=_sigint_default)
        out = Lines(proc)
        try:
            assert out.wait_for(r"\S", 30.0), out.text()
            if "/uav1/setpoint" in command:
                # Fed, not just published: the companion took the setpoints in (and, with no offboard
                # session, did not forward them); a wrong type or a missing client_id shows up here.
                verdict = r"setpoint_ignored \[cli\]|type mismatch|setpoint_rejected"
                assert companion.wait_for(verdict, 30.0), companion.text()[-3000:]
                assert not re.search(r"type mismatch|setpoint_rejected", companion.text()), companion.text()[-3000:]
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
        assert proc.returncode == 0 and "Traceback" not in out.text(), out.text()
        return
    r = cli(*argv[1:], timeout=60)
    assert r.returncode == 0, f"{command}\n{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stderr and r.stdout.strip(), f"{command}\n{r.stdout}\n{r.stderr}"
