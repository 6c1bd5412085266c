"""``zenoh-robot demo``: run a small system on localhost and show live statistics."""
from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the demo system on localhost")
    p.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Two processes: the talker publishes setpoints, the listener prints age and period."""
    ns = f"demo{int(time.time()) % 100000}"
    procs = [subprocess.Popen([sys.executable, str(ROOT / "examples" / name), "--ns", ns])
             for name in ("listener.py", "talker.py")]
    try:
        deadline = time.monotonic() + args.duration
        while time.monotonic() < deadline and all(p.poll() is None for p in procs):
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
    return 0
