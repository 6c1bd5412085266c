"""The `zenoh-robot` CLI as the tests run it: its own process, as a user's terminal would.

- ``CLI``: the command line (this venv's Python running the CLI's ``main``); ``CLI_ARGS`` the same
  without the interpreter, for ``python_proc(*CLI_ARGS, ...)``.
- ``INTERACTIVE_CLI``: as from a terminal, where Ctrl-C turns into KeyboardInterrupt.
- ``cli(*args)``: one command to its end, output captured.
- ``TOPIC_TALKER``: the script conftest's ``talker`` fixture runs for the topic CLI modules.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CLI = [sys.executable, "-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())"]
CLI_ARGS = tuple(CLI[1:])

# As from a terminal: a test run started in the background (`pytest &`) passes an ignored
# SIGINT on to its children, and Python then never turns Ctrl-C into KeyboardInterrupt.
INTERACTIVE_CLI = [sys.executable, "-c", "import signal, sys; "
                   "signal.signal(signal.SIGINT, signal.default_int_handler); "
                   "from zenoh_robot.tools.cli.main import main; sys.exit(main())"]

# Not passed on to the CLI: Zenoh's log filter and the colour switch would change what it prints.
_DROPPED_ENV = ("RUST_LOG", "NO_COLOR")


def cli(*args: str, timeout: float = 60.0, env: dict[str, str] | None = None,
        merged: bool = False) -> subprocess.CompletedProcess[str]:
    """``zenoh-robot *args`` in its own process, run to its end; stdout and stderr apart, or with
    ``merged`` both in ``stdout`` (unbuffered, in the order they were written)."""
    full = {k: v for k, v in os.environ.items() if k not in _DROPPED_ENV}
    full.update(env or {})
    if merged:
        full["PYTHONUNBUFFERED"] = "1"
        return subprocess.run([*CLI, *args], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, timeout=timeout, env=full)
    return subprocess.run([*CLI, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=full)


def cli_seeing(ns: str, *args: str, tries: int = 3) -> subprocess.CompletedProcess[str]:
    """``cli(*args)`` again (at most ``tries`` times) until its output names the talker's namespace. `topic list`
    ends once the graph is quiet for 0.5 s, and a fresh session on a loaded machine can find the talker's
    domain quiet before its entities arrive: what is tested here is what a listing shows, not that race."""
    for _ in range(tries - 1):
        out = cli(*args)
        if out.returncode != 0 or f"/{ns}/" in out.stdout:
            return out
    return cli(*args)


# The talker of the topic CLI modules (test_cli_topic, test_cli_more), argv[1]: its namespace.
# A BEST_EFFORT String stream with a RELIABLE (so incompatible) subscription beside it, a Setpoint
# stream, a type the CLI does not know, a TRANSIENT_LOCAL topic published once at start, and
# TopicStatistics published by hand so `stats` is tested apart from the statistics module.
TOPIC_TALKER = r"""
import sys
from zenoh_robot import Message, Node, message, msgs, qos
from zenoh_robot.qos import QoSProfile

@message(name="test_msgs/Secret")   # registered only in this process
class Secret(Message):
    code: int = 0

ns = sys.argv[1]
with Node("talker", namespace=ns) as n:
    chatter = n.create_publisher(msgs.String, "chatter", qos.SENSOR)          # BEST_EFFORT
    n.create_subscription(msgs.String, "chatter", lambda m: None, QoSProfile(reliability="reliable"))
    setpoint = n.create_publisher(msgs.Setpoint, "setpoint", qos.SETPOINT)
    secret = n.create_publisher(Secret, "secret")
    stats = n.create_publisher(msgs.TopicStatistics, f"/{ns}/statistics/chatter")
    latched = n.create_publisher(msgs.String, "latched", qos.CONFIGURATION)   # TRANSIENT_LOCAL
    latched.publish(msgs.String("kept for late joiners"))
    print("ready", flush=True)
    i = 0
    while True:
        chatter.publish(msgs.String(f"hello {i}"))
        setpoint.publish(msgs.Setpoint(msgs.Header.now(), x=1.5, y=float(i)))
        secret.publish(Secret(42))
        if i % 5 == 0:
            stats.publish(msgs.TopicStatistics(
                topic=f"/{ns}/chatter", node=f"/{ns}/listener", received=i, lost=2, dropped=1,
                message_age_ms=msgs.StatisticsEntry(1.5, 0.5, 3.0, 0.4, 20),
                message_period_ms=msgs.StatisticsEntry(50.0, 48.0, 52.0, 1.0, 20)))
        i += 1
        n.spin(0.05)   # ~20 Hz
"""
