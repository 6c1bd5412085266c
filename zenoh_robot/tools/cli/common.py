"""What every network command shares: the session flags' config, a hidden node, Ctrl-C, names, types."""
from __future__ import annotations

import argparse
import contextlib
import difflib
import functools
import os
import secrets
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.message import Message
    from zenoh_robot.node import Node
    from zenoh_robot.session_config import SessionConfig
    from zenoh_robot.wire import WireFormat

HIDDEN_PREFIX = "_zr_"        # the CLI's own nodes: left out of list/info unless --all


# -- the session: the library's flags (zenoh_robot.session_args), read once here ---------------
def session_config(args: argparse.Namespace) -> "SessionConfig":
    """The session the flags of ``add_session_arguments`` ask for; a bad one is a one-line CliError."""
    from zenoh_robot.session_args import session_config_from_args
    from zenoh_robot.session_config import SessionConfigError

    path = getattr(args, "zenoh", None)
    if path is not None and not Path(path).is_file():
        raise CliError(f"--zenoh: no such file {path!r}")
    try:
        return session_config_from_args(args)
    except SessionConfigError as exc:
        raise CliError(one_line(str(exc))) from None


def wire_of(args: argparse.Namespace) -> "WireFormat":
    """The wire format of ``--ros2`` / ``--ros-domain-id`` (else the envelope); a bad one is a CliError."""
    from zenoh_robot.session_args import wire_from_args

    try:
        return wire_from_args(args)
    except ValueError as exc:
        raise CliError(f"--ros-domain-id: {exc}") from None


def is_ros2(node: "Node") -> bool:
    """Whether ``node`` speaks ROS 2's wire (its types are then ROS 2 types: ``ros2_type``)."""
    return node.wire.name == "ros2"


def add_duration_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, metavar="S", help="exit after S seconds")


def deadline_of(args: argparse.Namespace) -> float | None:
    duration: float | None = args.duration
    if duration is None:
        return None
    if not duration > 0:
        raise CliError(f"--duration must be > 0 seconds, got {duration:g}")
    return time.monotonic() + duration


def quiet_exit(fn: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Ctrl-C ends a command normally (exit 0, no traceback); so does a closed pipe (`| head`)."""
    @functools.wraps(fn)
    def wrapper(args: argparse.Namespace) -> int:
        try:
            return fn(args)
        except KeyboardInterrupt:
            return 0
        except BrokenPipeError:
            # Python would complain again flushing stdout at exit: point it at /dev/null.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
    return wrapper


@contextlib.contextmanager
def cli_node(kind: str, args: argparse.Namespace) -> Iterator["Node"]:
    """A hidden node (``_zr_<kind>_<hex>``) on the configured session, always closed."""
    from zenoh_robot.node import Node  # imported late so `zenoh-robot --help` stays fast
    from zenoh_robot.session_config import SessionConfigError

    config = session_config(args)
    wire = wire_of(args)
    try:
        node = Node(f"{HIDDEN_PREFIX}{kind}_{secrets.token_hex(3)}", config=config, wire=wire)
    except SessionConfigError as exc:
        raise CliError(one_line(str(exc))) from None
    try:
        warn_unreached(node, args)
        yield node
    finally:
        _close_uninterrupted(node)


def warn_unreached(node: "Node", args: argparse.Namespace) -> None:
    """One line on stderr per ``-e`` endpoint nothing answers: a peer opens without it, and a command
    would otherwise list an empty network and exit 0 as if all were well."""
    from zenoh_robot.endpoint_reach import unreached_endpoints
    from zenoh_robot.session_args import secure_twin

    endpoints: list[str] = list(getattr(args, "connect", None) or [])
    if getattr(args, "secure", None):
        endpoints = [e for e in (secure_twin(x) for x in endpoints) if e]
    if not endpoints:
        return
    for endpoint in unreached_endpoints(node.session, endpoints):
        print(f"zenoh-robot {getattr(args, 'command', '')}: cannot reach {endpoint} (is a router running there?)",
              file=sys.stderr, flush=True)


def _close_uninterrupted(node: "Node") -> None:
    # A second Ctrl-C halfway through close() would leave the session open and exit hanging on it.
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        node.close()
    finally:
        if previous is not None:   # None: a handler not set from Python, nothing to restore
            signal.signal(signal.SIGINT, previous)


class CallbackOutput:
    """stdout for text printed from callbacks, where the executor would catch (and log) a
    closed pipe: a reader gone (`| head`) is remembered, and ends the command."""

    def __init__(self) -> None:
        self.closed = False

    def print(self, text: str) -> None:
        if self.closed:
            return
        try:
            print(text, flush=True)
        except BrokenPipeError:
            self.closed = True

    def check(self) -> None:
        if self.closed:
            raise BrokenPipeError("stdout closed")


def one_line(text: str) -> str:
    return " ".join(text.split())


def spin_until(node: "Node", done: Callable[[], bool], deadline: float | None) -> None:
    """Run the node's callbacks on this thread until ``done()`` or the deadline."""
    while not done():
        wait = 0.1
        if deadline is not None:
            wait = min(wait, deadline - time.monotonic())
            if wait <= 0:
                return
        node.spin_once(wait)


def topic_key(topic: str) -> str:
    """``/a/b`` or ``a/b`` -> the Zenoh key ``a/b`` (validated by ROS 2's name rules)."""
    from zenoh_robot.names import InvalidNameError, resolve_topic

    try:
        return resolve_topic(topic if topic.startswith("/") else "/" + topic)
    except InvalidNameError as exc:
        raise CliError(str(exc)) from None


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """`` (did you mean /uav1/setpoint?)`` for a near miss, else ''. Never the name itself (nor it with
    another leading or trailing ``/``): a topic seen only through its subscribers is "known" yet not
    found, and suggesting what the user typed reads as a contradiction."""
    def same(a: str) -> str:
        return a.strip("/")

    others = [k for k in dict.fromkeys(known) if same(k) != same(name)]
    close = difflib.get_close_matches(name, others, n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(close)}?)" if close else ""


def is_msg_file(name: str) -> bool:
    return name.endswith(".msg")


def load_msg_file(path: str, package: str = "msg") -> type[Message]:
    from zenoh_robot.msg_loader import MsgParseError, load_msg

    if not Path(path).is_file():
        raise CliError(f"no such .msg file {path!r}")
    try:
        return load_msg(Path(path), package=package)
    except MsgParseError as exc:
        raise CliError(str(exc)) from None


def lookup_type(name: str, ros2: bool = False) -> type[Message]:
    """A registered type by name (``Setpoint``, ``std_msgs/String``), or a ``.msg`` file's; with
    ``ros2``, the ROS 2 type of that name (``std_msgs/msg/String``), as ROS 2 nodes send it."""
    from zenoh_robot import msgs  # noqa: F401  registers the standard types
    from zenoh_robot.message import lookup

    if ros2 and not is_msg_file(name):
        return ros2_lookup(name)
    if is_msg_file(name):
        return load_msg_file(name)
    register_message_types()
    try:
        return lookup(name)
    except KeyError as exc:
        raise CliError(str(exc.args[0])) from None


def ros2_lookup(name: str) -> type[Message]:
    """The ROS 2 message type ``name`` (rosbags' standard packages, or one loaded before)."""
    try:
        from zenoh_robot.ros2 import ros2_type

        return ros2_type(name)
    except ImportError as exc:
        raise CliError(str(exc)) from None
    except (KeyError, ValueError) as exc:
        raise CliError(one_line(str(exc.args[0] if exc.args else exc))) from None


_types_registered = False


# The library's message types outside zenoh_robot.msgs: registered when their module is imported, which a
# command that only reads the graph (topic hz of /uav1/image's ImageSlice, bag record) would never do.
LIBRARY_MESSAGE_MODULES = ("zenoh_robot.msgs", "zenoh_robot.image.sliced", "zenoh_robot.image.fec",
                           "zenoh_robot.loss_feedback", "zenoh_robot.parameters.service")


def register_message_types() -> None:
    """Register every message type a command may meet by name: the library's own, and those of the
    modules applications declare (entry-point group ``zenoh_robot.messages``), so the tools read
    /uav1/state by name without importing the drone system themselves."""
    global _types_registered
    if _types_registered:
        return
    _types_registered = True
    import importlib
    from importlib.metadata import entry_points

    for name in LIBRARY_MESSAGE_MODULES:
        importlib.import_module(name)
    for ep in entry_points(group="zenoh_robot.messages"):
        with contextlib.suppress(Exception):   # a broken plugin costs its types, not the command
            ep.load()
