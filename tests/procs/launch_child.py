"""A process for the launch tests: prints its pid, ticks, optionally fails, spawns a grandchild
or ignores SIGINT."""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

parser = argparse.ArgumentParser()
parser.add_argument("--fail-after", type=float, help="exit with --code after this many seconds")
parser.add_argument("--code", type=int, default=3)
parser.add_argument("--grandchild", action="store_true", help="start a long-sleeping grandchild")
parser.add_argument("--ignore-sigint", action="store_true")
args, rest = parser.parse_known_args()

if args.ignore_sigint:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
print(f"pid {os.getpid()} args {rest}", flush=True)
if args.grandchild:
    gc = subprocess.Popen([sys.executable, "-c", "import os, time; print('grandchild pid', os.getpid(), "
                                                 "flush=True); time.sleep(120)"])
start = time.monotonic()
try:
    i = 0
    while True:
        if args.fail_after is not None and time.monotonic() - start >= args.fail_after:
            print("failing now", flush=True)
            sys.exit(args.code)
        print(f"tick {i}", flush=True)
        i += 1
        time.sleep(0.1)
except KeyboardInterrupt:
    print("interrupted, bye", flush=True)
