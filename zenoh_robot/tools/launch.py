"""Launch files: start a set of processes from YAML, prefix their output, stop them together.

Format (every key but ``processes`` optional; unknown keys are errors)::

    args:                         # $(arg NAME) anywhere below; NAME:=VALUE on the command line
      ns: uav1                    # a default ...
      reliability: {default: best_effort, description: QoS of the streams}
      px4: {description: required, no default}
    include:                      # other launch files, relative to this one
      - file: sim.yaml
        args: {ns: $(arg ns)}
    processes:
      - name: companion           # unique; prefixes every output line
        exec: zenoh-robot companion --id $(arg ns)   # or  module: companion  or  cmd: [prog, arg, ...]
        args: [--verbose]         # appended to the command
        params: {reliability: $(arg reliability), depth: 5}   # appended as -p NAME:=VALUE
        env: {RUST_LOG: warn}
        cwd: .
        delay: 1.0                # seconds after launch before starting
        required: true            # default: when it exits, stop everything
        respawn: false            # restart it when it exits (then it never stops the launch)
        respawn_delay: 1.0
        depends_on: [sim]         # stopped before these (default: every process listed before it)

Substitutions: ``$(arg NAME)``, ``$(env NAME)`` / ``$(env NAME DEFAULT)``, ``$(python)``
(this interpreter), ``$(dirname)`` (the launch file's directory).

Relative paths are the launch file's: an argument of ``cmd``/``exec``/``args`` (or a ``--flag=value``'s
value) naming something beside the launch file, and not in the working directory, is passed as that
absolute path, so a launch file finds its neighbours (``--zenoh client.json5``, ``--secure keys``)
wherever it is started from; ``cwd`` and ``include`` are relative to it as well.

Stopping (Ctrl-C, SIGTERM, ``duration`` or a required process exiting) goes in reverse
dependency order: dependents first (a companion commands HOLD while its simulator still
runs), and each group is stopped before what it depends on is signalled. Per group:
SIGINT, then SIGTERM after ``sigint_timeout``, then SIGKILL after ``sigterm_timeout``;
a second Ctrl-C skips ahead. Each process runs in its own
process group (a stop reaches its children too) and, on Linux, dies with the runner.
Exit code: 0 after a requested stop or a clean end, 1 when a required process failed.
"""
from __future__ import annotations

import ctypes
import itertools
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import yaml

from zenoh_robot.parameters import format_param_value, parse_param_value


class LaunchError(ValueError):
    """A launch file or argument problem; the message names the file and the entry."""


PROCESS_KEYS = {"name", "cmd", "exec", "module", "args", "params", "env", "cwd", "delay", "required",
                "respawn", "respawn_delay", "depends_on"}
TOP_KEYS = {"args", "include", "processes"}
# Not `-m zenoh_robot.tools.cli.main`: that runs main.py as __main__, a second copy whose CliError
# the subcommands do not raise, so user errors would print tracebacks.
_ZENOH_ROBOT = [sys.executable, "-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())"]
_SUBST = re.compile(r"\$\((\w+)(?:\s+([^)\s]+))?(?:\s+([^)]*))?\)")
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")
# What a Python process is started as (a spec's argv stays as written: it is what the log shows). A stop
# (SIGINT) can come while the process is still importing, a second or more on a loaded machine, before any
# handler of its own: these end it quietly, exit 130, where Python would print a KeyboardInterrupt traceback.
_GUARDED_ZENOH_ROBOT = [sys.executable, "-c", "import sys\ntry:\n    from zenoh_robot.tools.cli.main import main\n"
                        "except KeyboardInterrupt:\n    sys.exit(130)\nsys.exit(main())"]
_GUARDED_MODULE = ("import runpy, sys\nmodule = sys.argv.pop(1)\ntry:\n"
                   "    runpy.run_module(module, run_name='__main__', alter_sys=True)\n"
                   "except KeyboardInterrupt:\n    sys.exit(130)\n")


def _guarded(argv: list[str]) -> list[str]:
    """``argv`` as started: ``python -m M`` and ``zenoh-robot`` quiet when stopped during their imports."""
    if argv[:3] == _ZENOH_ROBOT:
        return _GUARDED_ZENOH_ROBOT + argv[3:]
    if len(argv) >= 3 and argv[0] == sys.executable and argv[1] == "-m":
        return [sys.executable, "-c", _GUARDED_MODULE, *argv[2:]]
    return argv


@dataclass
class ProcessSpec:
    name: str
    argv: list[str]
    env: dict[str, str] = field(default_factory=dict)
    cwd: str | None = None
    delay: float = 0.0
    required: bool = True
    respawn: bool = False
    respawn_delay: float = 1.0
    depends_on: list[str] | None = None    # None: every process declared before this one


@dataclass
class LaunchDescription:
    processes: list[ProcessSpec]
    source: str = "<python>"


# -- loading -------------------------------------------------------------------------------
def parse_launch_args(items: Sequence[str]) -> dict[str, str]:
    """``["ns:=uav2", "depth:=5"]`` -> ``{"ns": "uav2", "depth": "5"}``."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name.strip():
            raise LaunchError(f"bad launch argument {item!r}: expected NAME:=VALUE")
        out[name.strip()] = value
    return out


class _Context:
    def __init__(self, path: Path, args: dict[str, str]) -> None:
        self.path = path
        self.args = args

    def subst(self, text: str, where: str) -> str:
        def one(m: re.Match[str]) -> str:
            kind, name, default = m.group(1), m.group(2), m.group(3)
            if kind == "arg":
                if name not in self.args:
                    raise LaunchError(f"{where}: unknown launch argument $(arg {name}); "
                                      f"declared: {', '.join(sorted(self.args)) or 'none'}")
                return self.args[name]
            if kind == "env":
                if name is None:
                    raise LaunchError(f"{where}: $(env) needs a variable name")
                if name in os.environ:
                    return os.environ[name]
                if default is None:
                    raise LaunchError(f"{where}: environment variable {name} is not set "
                                      f"(give a default: $(env {name} VALUE))")
                return default
            if kind == "python":
                return sys.executable
            if kind == "dirname":
                return str(self.path.parent)
            raise LaunchError(f"{where}: unknown substitution $({kind} ...); use arg, env, python, dirname")
        return _SUBST.sub(one, text)

    def value(self, v: Any, where: str) -> Any:
        if isinstance(v, str):
            return self.subst(v, where)
        if isinstance(v, list):
            return [self.value(x, where) for x in v]
        if isinstance(v, dict):
            return {k: self.value(x, where) for k, x in v.items()}
        return v


def _as_argv(value: Any, where: str) -> list[str]:
    if isinstance(value, str):
        try:
            return shlex.split(value)
        except ValueError as exc:
            raise LaunchError(f"{where}: {exc}") from None
    if isinstance(value, list):
        bad = [x for x in value if isinstance(x, bool) or not isinstance(x, (str, int, float))]
        if bad:
            # YAML reads `false`, `yes`, `null` as values, not words: `cmd: [false]` is no program.
            raise LaunchError(f"{where}: argument {bad[0]!r} is a YAML {type(bad[0]).__name__}, not text; "
                              f"quote it (e.g. [\"{str(bad[0]).lower()}\"])")
        return [str(x) for x in value]
    raise LaunchError(f"{where}: expected a command line string or a list of arguments, got {value!r}")


def _beside(word: str, here: Path, cwd: Path) -> str:
    """``word`` (an argument, or ``--flag=value``'s value) made absolute when it is a relative path to
    something beside the launch file (``here``) and not in the process's working directory ``cwd``: a
    launch file names its own neighbours (a Zenoh config, a keys directory, a mission) wherever it is
    started from; a path the process finds where it runs is left to it, as is every other word."""
    flag, eq, value = word.partition("=") if word.startswith("-") else ("", "", word)
    if word.startswith("-") and not eq:
        return word
    if not value or "://" in value or Path(value).is_absolute():
        return word
    try:
        if (cwd / value).exists() or not (here / value).exists():
            return word
    except OSError:     # a name too long for a path, say: not a path
        return word
    return f"{flag}{eq}{os.path.normpath(here / value)}"


def _number(value: Any, where: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise LaunchError(f"{where}: {value!r} is not a number of seconds") from None
    if not v >= 0:
        raise LaunchError(f"{where}: must be >= 0 seconds, got {value!r}")
    return v


def _flag(value: Any, where: str) -> bool:
    if isinstance(value, str):
        parsed = parse_param_value(value)
        value = parsed if isinstance(parsed, bool) else value
    if not isinstance(value, bool):
        raise LaunchError(f"{where}: expected true or false, got {value!r}")
    return value


def _process(entry: Any, ctx: _Context, where: str) -> ProcessSpec:
    if not isinstance(entry, dict):
        raise LaunchError(f"{where}: each process is a mapping with at least name and a command")
    name = entry.get("name")
    if isinstance(name, str):
        name = ctx.subst(name, where)   # `sim_$(arg ns)`: one include per drone, distinct names
    if not isinstance(name, str) or not _NAME.match(name):
        raise LaunchError(f"{where}: needs a name (letters, digits, '_', '-', '.'), got {name!r}")
    where = f"{where} ({name!r})"
    unknown = sorted(set(entry) - PROCESS_KEYS)
    if unknown:
        raise LaunchError(f"{where}: unknown key(s) {', '.join(unknown)}; valid keys: "
                          f"{', '.join(sorted(PROCESS_KEYS))}")
    commands = [k for k in ("cmd", "exec", "module") if k in entry]
    if len(commands) != 1:
        raise LaunchError(f"{where}: needs exactly one of cmd, exec, module"
                          + (f" (has {', '.join(commands)})" if commands else ""))
    kind = commands[0]
    raw = ctx.value(entry[kind], f"{where}.{kind}")
    words: list[str] = []       # what the file wrote: its relative paths are the file's (_beside)
    if kind == "module":
        if not isinstance(raw, str) or not raw.strip():
            raise LaunchError(f"{where}.module: expected a Python module name, got {raw!r}")
        argv = [sys.executable, "-m", raw.strip()]
    else:
        words = _as_argv(raw, f"{where}.{kind}")
        if not words:
            raise LaunchError(f"{where}.{kind}: empty command")
        argv = []
        if kind == "exec":
            # The venv's own entry point, whether or not `zenoh-robot` is on PATH.
            argv = list(_ZENOH_ROBOT)
            words = words[1:] if words[0] == "zenoh-robot" else words
    if "args" in entry:
        words += _as_argv(ctx.value(entry["args"], f"{where}.args"), f"{where}.args")
    cwd = entry.get("cwd")
    if cwd is not None:
        cwd_path = Path(str(ctx.value(cwd, f"{where}.cwd")))
        cwd = str(cwd_path if cwd_path.is_absolute() else ctx.path.parent / cwd_path)
    argv += [_beside(w, ctx.path.parent, Path(cwd) if cwd else Path.cwd()) for w in words]
    params = entry.get("params") or {}
    if not isinstance(params, dict):
        raise LaunchError(f"{where}.params: expected a mapping of parameter names to values")
    for pname, pvalue in params.items():
        pw = f"{where}.params.{pname}"
        if not isinstance(pname, str):
            raise LaunchError(f"{pw}: parameter names must be strings (YAML reads on/off/yes/no as "
                              "booleans: quote them)")
        if isinstance(pvalue, dict):
            raise LaunchError(f"{pw}: a parameter value is a scalar or a list, not a mapping")
        if isinstance(pvalue, str):
            substituted = ctx.subst(pvalue, pw)
            # A whole `$(arg x)` takes the type of the argument's text (5 -> int), as the node will.
            text = substituted if pvalue.strip().startswith("$(") and pvalue.strip().endswith(")") \
                else format_param_value(substituted)
        else:
            text = format_param_value(ctx.value(pvalue, pw))
        argv += ["-p", f"{pname}:={text}"]
    env = entry.get("env") or {}
    if not isinstance(env, dict):
        raise LaunchError(f"{where}.env: expected a mapping of variable names to values")
    env = {str(k): str(ctx.value(v, f"{where}.env.{k}")) if not isinstance(v, bool) else ("1" if v else "0")
           for k, v in env.items()}
    deps = entry.get("depends_on")
    if deps is not None:
        deps = ctx.value(deps, f"{where}.depends_on")
        if isinstance(deps, str):
            deps = [deps]
        if not isinstance(deps, list) or not all(isinstance(d, str) for d in deps):
            raise LaunchError(f"{where}.depends_on: expected a list of process names")
    return ProcessSpec(
        name=name, argv=argv, env=env, cwd=cwd, depends_on=deps,
        delay=_number(ctx.value(entry.get("delay", 0.0), where), f"{where}.delay"),
        required=_flag(ctx.value(entry.get("required", True), where), f"{where}.required"),
        respawn=_flag(ctx.value(entry.get("respawn", False), where), f"{where}.respawn"),
        respawn_delay=_number(ctx.value(entry.get("respawn_delay", 1.0), where), f"{where}.respawn_delay"))


def _declared_args(decl: Any, given: dict[str, str], where: str) -> dict[str, str]:
    if decl is None:
        decl = {}
    if not isinstance(decl, dict):
        raise LaunchError(f"{where}: args must be a mapping of argument names to defaults")
    unknown = sorted(set(given) - set(decl))
    if unknown:
        raise LaunchError(f"{where}: unknown launch argument(s) {', '.join(unknown)}; "
                          f"declared: {', '.join(sorted(decl)) or 'none'}")
    out = {}
    for name, spec in decl.items():
        if isinstance(spec, dict):
            extra = sorted(set(spec) - {"default", "description"})
            if extra:
                raise LaunchError(f"{where}: argument {name!r}: unknown key(s) {', '.join(extra)}; "
                                  "valid keys: default, description")
            default = spec.get("default")
        else:
            default = spec
        if name in given:
            out[str(name)] = given[name]
        elif default is None:
            raise LaunchError(f"{where}: launch argument {name!r} has no default: pass {name}:=VALUE")
        else:
            out[str(name)] = format_param_value(default) if not isinstance(default, str) else default
    return out


def load_launch(path: str | Path, args: dict[str, str] | None = None, _stack: tuple[Path, ...] = ()
                ) -> LaunchDescription:
    """Read, validate and resolve a launch file (includes and substitutions done)."""
    path = Path(path).resolve()
    if path in _stack:
        raise LaunchError(f"{path}: included recursively ({' -> '.join(p.name for p in (*_stack, path))})")
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise LaunchError(f"cannot read launch file {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise LaunchError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
    where = str(path)
    if not isinstance(data, dict):
        raise LaunchError(f"{where}: a launch file is a mapping with a 'processes' list")
    unknown = sorted(set(data) - TOP_KEYS)
    if unknown:
        raise LaunchError(f"{where}: unknown key(s) {', '.join(unknown)}; valid keys: {', '.join(sorted(TOP_KEYS))}")
    ctx = _Context(path, _declared_args(data.get("args"), dict(args or {}), where))
    processes: list[ProcessSpec] = []
    includes = data.get("include") or []
    if not isinstance(includes, list):
        raise LaunchError(f"{where}: include must be a list")
    for i, inc in enumerate(includes):
        iw = f"{where}: include[{i}]"
        if isinstance(inc, str):
            inc = {"file": inc}
        if not isinstance(inc, dict) or "file" not in inc or set(inc) - {"file", "args"}:
            raise LaunchError(f"{iw}: expected a file name or {{file: NAME, args: {{...}}}}")
        inc_args = ctx.value(inc.get("args") or {}, iw)
        if not isinstance(inc_args, dict):
            raise LaunchError(f"{iw}: args must be a mapping")
        inc_path = Path(ctx.subst(str(inc["file"]), iw))
        inc_path = inc_path if inc_path.is_absolute() else path.parent / inc_path
        sub = load_launch(inc_path, {str(k): v if isinstance(v, str) else format_param_value(v)
                                     for k, v in inc_args.items()}, (*_stack, path))
        processes += sub.processes
    entries = data.get("processes")
    if entries is None and not processes:
        raise LaunchError(f"{where}: no 'processes' list")
    if entries is not None and not isinstance(entries, list):
        raise LaunchError(f"{where}: 'processes' must be a list")
    for i, entry in enumerate(entries or []):
        processes.append(_process(entry, ctx, f"{where}: processes[{i}]"))
    seen: set[str] = set()
    for p in processes:
        if p.name in seen:
            raise LaunchError(f"{where}: two processes are named {p.name!r}")
        seen.add(p.name)
    for p in processes:
        for d in p.depends_on or []:
            if d not in seen or d == p.name:
                raise LaunchError(f"{where}: process {p.name!r} depends_on {d!r}, which is not another process "
                                  f"here ({', '.join(sorted(seen - {p.name}))})")
    stop_order(processes)   # refuses a cycle now, not at Ctrl-C
    return LaunchDescription(processes, where)


def stop_order(specs: Sequence[ProcessSpec]) -> list[list[str]]:
    """Groups of process names to stop one after the other: dependents before what they depend on.

    Without ``depends_on``, a process depends on every one declared before it, so the
    launch stops in reverse order of declaration.
    """
    names = [s.name for s in specs]
    deps = {s.name: set(names[:i]) if s.depends_on is None else set(s.depends_on) for i, s in enumerate(specs)}
    left = set(names)
    groups: list[list[str]] = []
    while left:
        # Nothing still running depends on these: they go now.
        free = [n for n in names if n in left and not any(n in deps[o] for o in left if o != n)]
        if not free:
            raise LaunchError(f"depends_on forms a cycle among {', '.join(sorted(left))}")
        groups.append(free)
        left -= set(free)
    return groups


# -- running -------------------------------------------------------------------------------
_COLORS = ["cyan", "magenta", "green", "yellow", "blue", "bright_cyan", "bright_magenta", "bright_green"]


def _die_with_parent() -> None:
    # Linux: the child gets SIGTERM if the runner dies without stopping it (e.g. SIGKILL).
    try:
        libc = ctypes.CDLL(None)
        libc.prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
        # A launch stops its processes with SIGINT; started from a shell's background job (`&`), SIGINT
        # comes ignored, and an ignored SIGINT stays ignored across exec: the process would not stop
        # until SIGTERM or SIGKILL, without its summary. (libc's, not Python's signal(): this runs
        # between fork and exec, maybe off the main thread.)
        libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
        libc.signal(signal.SIGINT, None)   # SIG_DFL
    except Exception:
        pass


class _Output:
    """Serialised, prefixed line output; colored with rich when writing to a terminal."""

    def __init__(self, stream: IO[str], width: int, color: bool | None) -> None:
        self.stream = stream
        self.width = width
        self.lock = threading.Lock()
        self.color = stream.isatty() if color is None and hasattr(stream, "isatty") else bool(color)
        self.console = None
        if self.color:
            from rich.console import Console
            self.console = Console(file=stream, highlight=False, markup=False, soft_wrap=True,
                                   force_terminal=True)
        self._styles: dict[str, str] = {}
        self._next = itertools.cycle(_COLORS)

    def line(self, name: str, text: str, style: str | None = None) -> None:
        prefix = f"[{name}]".ljust(self.width + 2)
        with self.lock:
            if self.console is not None:
                from rich.text import Text
                if style is None:
                    style = self._styles.setdefault(name, next(self._next))
                self.console.print(Text.assemble((prefix, f"bold {style}"), " ", text))
            else:
                try:
                    self.stream.write(f"{prefix} {text}\n")
                    self.stream.flush()
                except (OSError, ValueError):
                    pass   # our own output closed: keep supervising


class _Proc:
    def __init__(self, spec: ProcessSpec) -> None:
        self.spec = spec
        self.popen: subprocess.Popen[bytes] | None = None
        self.reader: threading.Thread | None = None
        self.start_at = spec.delay
        self.returncode: int | None = None
        self.starts = 0


class LaunchRunner:
    """Run a launch description: ``LaunchRunner.from_file("demo.yaml").run(duration=60)``.

    ``run()`` blocks until everything has stopped and returns the exit code; call
    ``request_stop()`` from another thread (or send SIGINT/SIGTERM when run() is on
    the main thread) to stop early. ``failed`` names the required process that ended
    the launch and its exit code; ``returncodes`` holds each process's last exit code.
    """

    def __init__(self, description: LaunchDescription | Sequence[ProcessSpec], *,
                 output: IO[str] | None = None, color: bool | None = None,
                 sigint_timeout: float = 5.0, sigterm_timeout: float = 3.0, poll_interval: float = 0.05) -> None:
        if not isinstance(description, LaunchDescription):
            description = LaunchDescription(list(description))
        if not description.processes:
            raise LaunchError(f"{description.source}: nothing to launch")
        self.description = description
        self.procs = [_Proc(s) for s in description.processes]
        width = max([len(p.spec.name) for p in self.procs] + [len("launch")])
        self.out = _Output(output or sys.stdout, width, color)
        self.sigint_timeout = sigint_timeout
        self.sigterm_timeout = sigterm_timeout
        self.poll_interval = poll_interval
        self.failed: tuple[str, int] | None = None
        self.returncodes: dict[str, int | None] = {p.spec.name: None for p in self.procs}
        self._stop = threading.Event()
        self._stop_reason = ""
        self._stop_requests = 0
        self._lock = threading.Lock()

    @classmethod
    def from_file(cls, path: str | Path, args: dict[str, str] | None = None, **kw: Any) -> "LaunchRunner":
        return cls(load_launch(path, args), **kw)

    def log(self, text: str) -> None:
        self.out.line("launch", text, style="bold white")

    def request_stop(self, reason: str = "stop requested") -> None:
        with self._lock:
            self._stop_requests += 1
            if not self._stop_reason:
                self._stop_reason = reason
        self._stop.set()

    # -- processes ----------------------------------------------------------------------
    def _start(self, proc: _Proc) -> None:
        spec = proc.spec
        env = dict(os.environ, PYTHONUNBUFFERED="1", **spec.env)
        proc.starts += 1
        try:
            proc.popen = subprocess.Popen(_guarded(spec.argv), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                          stdin=subprocess.DEVNULL, env=env, cwd=spec.cwd,
                                          start_new_session=True, preexec_fn=_die_with_parent)
        except OSError as exc:
            self.log(f"cannot start {spec.name!r} ({shlex.join(spec.argv)}): {exc.strerror or exc}")
            proc.popen = None
            proc.returncode = 127
            return
        proc.returncode = None
        self.log(f"started {spec.name!r} (pid {proc.popen.pid}): {shlex.join(spec.argv)}")
        proc.reader = threading.Thread(target=self._pump, args=(proc.popen, spec.name), daemon=True,
                                       name=f"launch-{spec.name}")
        proc.reader.start()

    def _pump(self, popen: subprocess.Popen[bytes], name: str) -> None:
        assert popen.stdout is not None
        for raw in iter(popen.stdout.readline, b""):
            self.out.line(name, raw.decode("utf-8", "replace").rstrip("\r\n"))
        popen.stdout.close()

    def _signal_all(self, sig: int) -> None:
        for proc in self.procs:
            if proc.popen is not None and proc.popen.poll() is None:
                try:
                    os.killpg(proc.popen.pid, sig)
                except (ProcessLookupError, PermissionError):
                    pass

    def _running(self) -> list[_Proc]:
        return [p for p in self.procs if p.popen is not None and p.popen.poll() is None]

    def _reap(self, proc: _Proc) -> None:
        assert proc.popen is not None
        code = proc.popen.returncode
        if proc.reader is not None:
            proc.reader.join(timeout=1.0)   # its last lines come before our message
        proc.returncode = code
        self.returncodes[proc.spec.name] = code
        proc.popen = None

    @staticmethod
    def _describe_code(code: int) -> str:
        if code < 0:
            try:
                return f"signal {signal.Signals(-code).name}"
            except ValueError:
                return f"signal {-code}"
        return f"exit code {code}"

    # -- the run loop ---------------------------------------------------------------------
    def run(self, duration: float | None = None, handle_signals: bool = True) -> int:
        previous: dict[signal.Signals, Any] = {}
        if handle_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, lambda s, f: self.request_stop(
                    f"{signal.Signals(s).name} received"))
        try:
            return self._run(duration)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _run(self, duration: float | None) -> int:
        t0 = time.monotonic()
        pending = sorted(self.procs, key=lambda p: p.start_at)
        exit_code = 0
        while not self._stop.is_set():
            now = time.monotonic() - t0
            if duration is not None and now >= duration:
                self.request_stop(f"duration of {duration:g} s reached")
                break
            for proc in [p for p in pending if p.start_at <= now]:
                pending.remove(proc)
                self._start(proc)
                if proc.popen is None:   # could not start at all
                    self.returncodes[proc.spec.name] = proc.returncode
                    if proc.spec.required:
                        self.failed = (proc.spec.name, proc.returncode or 127)
                        self.request_stop(f"required process {proc.spec.name!r} could not start")
                        exit_code = 1
                        break
            if self._stop.is_set():
                break
            for proc in self.procs:
                if proc.popen is None or proc.popen.poll() is None:
                    continue
                self._reap(proc)
                code = proc.returncode or 0
                spec = proc.spec
                what = self._describe_code(code)
                if spec.respawn:
                    self.log(f"process {spec.name!r} exited ({what}); respawning in {spec.respawn_delay:g} s")
                    proc.start_at = time.monotonic() - t0 + spec.respawn_delay
                    pending.append(proc)
                elif spec.required:
                    self.failed = (spec.name, code)
                    if code != 0:
                        exit_code = 1
                        self.log(f"required process {spec.name!r} failed ({what}); stopping everything")
                    else:
                        self.log(f"required process {spec.name!r} finished ({what}); stopping everything")
                    self.request_stop(f"{spec.name!r} exited")
                    break
                else:
                    self.log(f"process {spec.name!r} exited ({what})")
            if self._stop.is_set():
                break
            if not pending and not self._running():
                self.log("all processes exited")
                break
            self._stop.wait(self.poll_interval)
        if self._stop_reason and not self.failed:
            self.log(f"{self._stop_reason}; stopping")
        self._shutdown()
        return exit_code

    def _shutdown(self) -> None:
        by_name = {p.spec.name: p for p in self.procs}
        for group in stop_order([p.spec for p in self.procs]):
            self._shutdown_group([by_name[n] for n in group])

    def _shutdown_group(self, procs: list[_Proc]) -> None:
        phases = [(signal.SIGINT, self.sigint_timeout), (signal.SIGTERM, self.sigterm_timeout),
                  (signal.SIGKILL, 2.0)]
        requests_seen = self._stop_requests

        def running() -> list[_Proc]:
            return [p for p in procs if p.popen is not None and p.popen.poll() is None]

        for sig, timeout in phases:
            alive = running()
            if not alive:
                break
            if sig != signal.SIGINT:
                self.log(f"sending {sig.name} to {', '.join(repr(p.spec.name) for p in alive)}")
            for proc in alive:
                try:
                    os.killpg(proc.popen.pid, sig)   # type: ignore[union-attr]
                except (ProcessLookupError, PermissionError):
                    pass
            deadline = time.monotonic() + timeout
            while running() and time.monotonic() < deadline:
                if self._stop_requests > requests_seen:   # another Ctrl-C: escalate now
                    requests_seen = self._stop_requests
                    break
                time.sleep(0.02)
        for proc in procs:
            if proc.popen is not None:
                try:
                    proc.popen.wait(timeout=2.0)
                except subprocess.TimeoutExpired:
                    self.log(f"process {proc.spec.name!r} (pid {proc.popen.pid}) survived SIGKILL")
                    continue
                self._reap(proc)
                self.log(f"process {proc.spec.name!r} stopped ({self._describe_code(proc.returncode or 0)})")
