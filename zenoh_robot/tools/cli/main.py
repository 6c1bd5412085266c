"""zenoh-robot: ROS 2-style nodes, QoS and tools over Zenoh, and the drone GCS/companion.

Each subcommand lives in its own module with ``register(sub)``, which adds a parser
and sets ``func(args) -> int``. Built-in ones are modules of this package; the
applications (gcs, companion, the PX4 simulator) plug in through the
``zenoh_robot.cli`` entry-point group, so this package never imports them (nor MAVLink).

A user's mistake (a missing file, a busy port, a bad value) ends the command with one
line on stderr and a non-zero exit; ``-v`` adds the traceback. Zenoh's own log (Rust,
written to stdout with colour codes) is off unless ``-v`` or ``RUST_LOG`` asks for it.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any, TypeAlias, cast

# Others (security: keys, router) append theirs; a module that does not exist yet is skipped.
SUBCOMMANDS = ["topic", "node", "interface", "stats", "param", "service", "action", "launch", "doctor", "completion",
               "bench", "keys", "router", "bag", "foxglove",
               "linkshim"]
EXIT_USER_ERROR = 1


class CliError(Exception):
    """An error to print as one line, exiting non-zero."""


if TYPE_CHECKING:   # the stubs' generic is not subscriptable at run time
    _SubParsersBase = argparse._SubParsersAction[argparse.ArgumentParser]
else:
    _SubParsersBase = argparse._SubParsersAction
SubParsers: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"   # what a plugin's register() gets


class _SubParsers(_SubParsersBase):
    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        parser: argparse.ArgumentParser = super().add_parser(name, **kwargs)
        if isinstance(parser, Parser):
            parser.is_subcommand = True
        return parser


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose subcommands report their own usage errors.

    Plain argparse hands a subcommand's unknown options back to the top-level parser,
    which then prints the top-level usage; here the subcommand's parser complains.
    A parser with ``intermixed`` set takes stray positionals into that list instead
    (``launch FILE --show x:=1``).
    """

    is_subcommand = False
    intermixed: str | None = None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.register("action", "parsers", _SubParsers)   # nested subcommands, too

    def parse_known_args(self, args: Sequence[str] | None = None,   # type: ignore[override]
                         namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:
        ns, extras = super().parse_known_args(args, namespace)
        if extras and self.intermixed:
            late = [e for e in extras if not e.startswith("-")]
            if late:
                setattr(ns, self.intermixed, [*(getattr(ns, self.intermixed, None) or []), *late])
                extras = [e for e in extras if e.startswith("-")]
        if extras and self.is_subcommand:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns, extras


# One log format for every program of the project (the CLI, companion, GCS and both simulators): a
# log collector parses them all alike; tests/tools/test_log_format.py holds them to it.
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def package_version() -> str:
    # The package's own __version__ is the one source (pyproject reads it); installed metadata
    # lags behind an editable checkout until it is reinstalled.
    from zenoh_robot import __version__

    return __version__


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command tree; with ``command``, only the part that serves it when that part alone
    registers it (a built-in module or an entry point of that name), else the whole tree.

    Registering every subcommand imports the applications and the doctor's plugins: 0.4 s of CPU
    that a one-shot command (``topic list``, ``node info``) would pay at every start.
    """
    if command is not None:
        parser, sub = _parser(command)
        if command in sub.choices:
            return parser
    return _parser(None)[0]


def _parser(only: str | None) -> tuple[argparse.ArgumentParser, SubParsers]:
    parser = Parser(prog="zenoh-robot", description=(__doc__ or "").splitlines()[0])
    _common_flags(parser)
    sub = cast(SubParsers, parser.add_subparsers(dest="command", metavar="COMMAND"))
    for name in SUBCOMMANDS:
        if only is not None and name != only:
            continue
        try:
            module = importlib.import_module(f"zenoh_robot.tools.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"zenoh_robot.tools.cli.{name}":
                continue
            raise
        module.register(sub)
    if only in sub.choices:
        return parser, sub
    for ep in sorted(entry_points(group="zenoh_robot.cli"), key=lambda e: e.name):
        if only is not None and ep.name != only:
            continue
        try:
            ep.load()(sub)
        except (ImportError, AttributeError) as exc:   # one broken plugin must not take the CLI down
            print(f"zenoh-robot: subcommand {ep.name!r} unavailable: {exc}", file=sys.stderr)
    return parser, sub


def _command_of(argv: Sequence[str]) -> str | None:
    """The subcommand a command line names: its first word that is not an option (the top-level
    options take no value)."""
    return next((a for a in argv if not a.startswith("-")), None)


def _common_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="debug logging, Zenoh's own warnings, and tracebacks for errors")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")


def quiet_zenoh_log(verbose: bool) -> None:
    """Zenoh logs from Rust straight to stdout, coloured, where it would mix with a command's
    output (``topic echo | ...``); zenoh-python 1.10 has no hook into Python logging. So: off
    unless asked (``-v`` or RUST_LOG), and without colour codes. Set in the environment so the
    processes ``demo`` and ``launch`` start inherit it."""
    if "RUST_LOG" not in os.environ:
        os.environ["RUST_LOG"] = "warn" if verbose else "off"
    os.environ.setdefault("NO_COLOR", "1")


def user_error(exc: BaseException) -> str | None:
    """One line for the exceptions a user's input causes; None for anything else (a bug)."""
    from zenoh_robot.graph import DuplicateNodeError
    from zenoh_robot.session_config import SessionConfigError

    if isinstance(exc, (CliError, DuplicateNodeError)):   # a second `companion --id uav1`: the message says it all
        return str(exc)
    if isinstance(exc, SessionConfigError):
        return f"Zenoh config: {exc}"
    if isinstance(exc, OSError):
        if exc.errno == errno.EADDRINUSE:
            return f"address already in use ({exc.strerror}): another program, or another copy of this one, " \
                   "holds the port; choose another port or stop it"
        if exc.errno == errno.EADDRNOTAVAIL:
            return f"cannot bind: address not available ({exc.strerror})"
        if exc.filename is not None:
            return f"{exc.strerror or exc}: {exc.filename}"
        return str(exc)
    try:
        import yaml
        if isinstance(exc, yaml.YAMLError):
            return f"invalid YAML: {exc}"
    except ImportError:   # pragma: no cover - PyYAML is a core dependency
        pass
    if isinstance(exc, (ValueError, LookupError)):
        return str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    return None


def main(argv: list[str] | None = None, parser: argparse.ArgumentParser | None = None) -> int:
    try:
        return _run_main(argv, parser)
    except KeyboardInterrupt:   # before the command's own Ctrl-C handling: importing, parsing, opening
        return 130


def _run_main(argv: list[str] | None, parser: argparse.ArgumentParser | None) -> int:
    parser = parser or build_parser(_command_of(sys.argv[1:] if argv is None else argv))
    args = parser.parse_args(argv)
    if getattr(args, "config_file", None) is not None:
        from .config_file import ConfigFileError, apply_config_file
        try:
            args = apply_config_file(parser, args, argv)
        except ConfigFileError as exc:
            print(f"zenoh-robot {args.command}: {exc}", file=sys.stderr)
            return 2
    verbose = bool(getattr(args, "verbose", False))
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format=LOG_FORMAT)
    quiet_zenoh_log(verbose)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    # The message types any command may meet on the graph (the library's image and parameter types, the
    # applications' entry points): once registered as a side effect of building the whole command tree.
    from .common import register_message_types
    register_message_types()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        text = user_error(exc)
        if text is None:
            raise
        if verbose:
            logging.getLogger("zenoh_robot.cli").exception("%s failed", args.command)
        print(f"zenoh-robot {args.command}: {' '.join(text.split())}", file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == "__main__":
    # Run as `python -m zenoh_robot.tools.cli.main`, this file is `__main__`, a second copy of the
    # module: subcommands raise the CliError of `zenoh_robot.tools.cli.main`, so call that copy's main.
    try:   # a stop while the package still imports: quietly, as main() does later
        from zenoh_robot.tools.cli.main import main as _main
    except KeyboardInterrupt:
        sys.exit(130)
    sys.exit(_main())


def run_single(register: Callable[[SubParsers], None], command: str, prog: str,
               argv: list[str] | None = None) -> int:
    """Run one plugin subcommand as its own program (``python -m gcs`` == ``zenoh-robot gcs``)."""
    try:
        parser = Parser(prog=prog)
        _common_flags(parser)
        # Parser subclasses ArgumentParser; the stubs make the action invariant in it.
        sub = cast(SubParsers, parser.add_subparsers(dest="command", required=True))
        register(sub)
    except KeyboardInterrupt:   # Ctrl-C (or a launch stopping us) while still starting: quietly
        return 130
    return main([command, *(sys.argv[1:] if argv is None else argv)], parser=parser)
