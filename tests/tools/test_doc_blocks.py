"""Every code block of README.md and docs/ is checked against the code (issue #39: a doc cannot drift).

Each block says, in a ``<!-- doc-test: KIND -->`` comment right above it, how it is held to the code:

- ``companion uav1``: run line by line against a companion (tests/tools/test_doc_examples.py);
- ``python ...``: run as a script (tests/tools/test_doc_examples_python.py);
- ``run``: shell commands run here, in an empty directory, one after the other: each exits 0, no traceback;
- ``shell``: commands that need a drone, a router, root, hardware or minutes: each command line is parsed
  by its program's own parser (``zenoh-robot``'s, a ``python -m`` module's ``main``, the Makefile's
  targets and variables), the repository paths it names exist, and only known programs appear;
- ``output``: what a program printed; its ``$ `` lines are commands, checked as ``shell``;
- ``fragment``: Python that names things defined around it: it compiles and its imports resolve;
- ``text``: a picture or a table, nothing to run.

A block without a marker fails here, so a new example is held to the code from its first commit.
"""
from __future__ import annotations

import argparse
import ast
import importlib
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path
from unittest import mock

import pytest
from cli_helpers import CLI
from conftest import fresh_domain
from doc_helpers import ROOT, Block, all_blocks

from zenoh_robot.tools.cli.main import build_parser

# Programs a doc may name besides ours: the system's, ROS 2's. Anything else is a typo or a shorthand a
# user cannot type (`gcs ...` for `zenoh-robot gcs ...`).
EXTERNAL = {"sudo", "sudoedit", "cp", "systemctl", "journalctl", "kill", "ros2", "grep", "ls", "cat", "export"}
OURS = {"zenoh-robot", ".venv/bin/zenoh-robot", "python", "python3", ".venv/bin/python", "make"}
SEPARATORS = {";", "&", "&&", "|", "||"}
KINDS = {"companion", "python", "run", "shell", "output", "fragment", "text"}
ALL = all_blocks()


def _kind(b: Block) -> str:
    return (b.kind or "").split()[0] if b.kind else ""


def test_every_block_says_how_it_is_checked() -> None:
    unmarked = [f"{b.where} ({b.lines[0][:50] if b.lines else ''!r})" for b in ALL if _kind(b) not in KINDS]
    assert not unmarked, "code blocks without a <!-- doc-test: KIND --> marker (KIND one of " \
                         f"{', '.join(sorted(KINDS))}):\n" + "\n".join(unmarked)
    assert len(ALL) > 40, [b.where for b in ALL]     # the scan finds the blocks at all


# ---------------------------------------------------------------------------------------------- commands

def commands(lines: list[str], prompt_only: bool = False) -> list[list[str]]:
    """The command lines of a shell block: continuations joined, comments dropped, split at ; & && | ||.
    Doc shorthand goes: ``[--opt value]`` (optional) is taken as written, ``...`` (more of the same) dropped."""
    text: list[str] = []
    for line in lines:
        if prompt_only:
            if not line.startswith("$ "):
                continue
            line = line[2:]
        if text and text[-1].endswith("\\"):
            text[-1] = text[-1][:-1] + " " + line.strip()
        else:
            text.append(line)
    out: list[list[str]] = []
    for line in text:
        lex = shlex.shlex(line, posix=True, punctuation_chars=";&|")
        lex.whitespace_split = True
        cmd: list[str] = []
        for tok in lex:
            if tok in SEPARATORS:
                out += [cmd] if cmd else []
                cmd = []
                continue
            tok = tok.removeprefix("[").removesuffix("]")
            if tok and tok != "...":
                cmd.append(tok)
        out += [cmd] if cmd else []
    return out


class _Parsed(Exception):
    pass


def _parse_with_main(module: str, argv: list[str]) -> None:
    """Run ``module.main(argv)`` only as far as its argument parser: the first parse ends it."""
    real = argparse.ArgumentParser.parse_args

    def parse_args(self: argparse.ArgumentParser, args: object = None, namespace: object = None) -> object:
        real(self, args, namespace)   # type: ignore[arg-type]
        raise _Parsed

    mod = importlib.import_module(module)
    if not hasattr(mod, "main"):    # a package run by its __main__, which calls its cli's main
        mod = importlib.import_module(f"{module}.cli")
    with mock.patch.object(argparse.ArgumentParser, "parse_args", parse_args):
        try:
            mod.main(argv)
        except _Parsed:
            return
    raise AssertionError(f"python -m {module}: main() returned without parsing its arguments")


def _makefile() -> tuple[set[str], set[str]]:
    text = (ROOT / "Makefile").read_text()
    targets = {t for m in re.finditer(r"^([\w .-]+):(?!=)", text, re.M) for t in m[1].split()}
    variables = set(re.findall(r"\$\((\w+)\)", text)) | set(re.findall(r"^(\w+)\s*[?:]?=", text, re.M))
    return targets, variables


def _repo_paths_exist(argv: list[str]) -> list[str]:
    """Paths into the repository's own folders that a command reads (outputs under docs/results and
    docs/img are written by the command)."""
    missing = []
    for tok in argv:
        path = tok.split("::")[0].split("=", 1)[-1]
        if re.match(r"(configs|tests|examples)/", path) and not (ROOT / path).exists():
            missing.append(path)
    return missing


def check_command(argv: list[str]) -> None:
    """AssertionError naming what is wrong with one documented command line."""
    while argv and re.match(r"[A-Z_][A-Z0-9_]*=", argv[0]):    # RUST_LOG=... zenoh-robot ...
        argv = argv[1:]
    prog, args = argv[0], argv[1:]
    assert not (missing := _repo_paths_exist(argv)), f"no such file in the repository: {missing}"
    if prog == "sudo":
        return check_command(args)
    if prog in EXTERNAL:
        return None
    assert prog in OURS, f"{prog!r} is no program a user has (`zenoh-robot {prog}`?)"
    if prog.endswith("zenoh-robot"):
        try:
            build_parser().parse_args(args)
        except SystemExit as exc:
            raise AssertionError(f"zenoh-robot's parser refuses it (exit {exc.code})") from None
    elif prog == "make":
        targets, variables = _makefile()
        for a in args:
            if "=" in a:
                assert a.split("=")[0] in variables, f"the Makefile has no variable {a.split('=')[0]}"
            else:
                assert a in targets, f"the Makefile has no target {a}"
    elif args[:1] == ["-c"]:
        compile(args[1], "<python -c>", "exec")
    else:
        assert args[:1] == ["-m"], "a Python command is `python -m MODULE` or `python -c CODE`"
        module = args[1]
        if module != "pytest":       # pytest's flags are pytest's; its paths are checked above
            try:
                _parse_with_main(module, args[2:])
            except SystemExit as exc:
                raise AssertionError(f"python -m {module}'s parser refuses it (exit {exc.code})") from None
    return None


SHELL = [(b.where, cmd) for b in ALL if _kind(b) in {"shell", "run", "companion", "output"}
         for cmd in commands(b.lines, prompt_only=_kind(b) == "output")]


def test_the_shell_blocks_have_commands() -> None:
    assert len(SHELL) > 60 and any(c[0] == "make" for _, c in SHELL), SHELL


@pytest.mark.fast
@pytest.mark.parametrize(("where", "argv"), SHELL, ids=[f"{w}:{' '.join(c)[:60]}" for w, c in SHELL])
def test_a_documented_command_is_one_the_programs_take(where: str, argv: list[str],
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    try:
        check_command(argv)
    except AssertionError as exc:
        err = capsys.readouterr().err.strip().splitlines()
        raise AssertionError(f"{where}: {shlex.join(argv)}\n  {exc}\n  {err[-1] if err else ''}") from None


# ---------------------------------------------------------------------------------------------- Python

PYTHON = [b for b in ALL if b.lang == "python" or _kind(b) == "fragment"]


@pytest.mark.fast
@pytest.mark.parametrize("block", PYTHON, ids=[b.where for b in PYTHON])
def test_a_python_block_compiles_and_its_imports_resolve(block: Block) -> None:
    assert _kind(block) in {"python", "fragment"}, f"{block.where}: a Python block is `python` or `fragment`"
    tree = ast.parse("\n".join(block.lines), block.where)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                importlib.import_module(alias.name)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            mod = importlib.import_module(node.module)
            for alias in node.names:
                assert hasattr(mod, alias.name) or importlib.util.find_spec(f"{node.module}.{alias.name}"), \
                    f"{block.where}: {node.module} has no {alias.name}"


# ---------------------------------------------------------------------------------------------- run

RUN = [b for b in ALL if _kind(b) == "run"]


@pytest.mark.parametrize("block", RUN, ids=[b.where for b in RUN])
def test_a_run_block_runs_as_written(block: Block, tmp_path: Path) -> None:
    env = {**os.environ, "ZR_DOMAIN": str(fresh_domain())}
    for argv in commands(block.lines):
        assert argv[0] == "zenoh-robot", f"{block.where}: a run block runs zenoh-robot commands: {argv}"
        r = subprocess.run([*CLI, *argv[1:]], cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 0 and "Traceback" not in r.stderr, \
            f"{block.where}: {shlex.join(argv)}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"


def test_there_are_run_blocks() -> None:
    assert RUN, "no block marked run"


if __name__ == "__main__":   # a quick look at the blocks and their kinds
    for b in ALL:
        print(b.where, b.kind, b.lines[:1], file=sys.stdout)
