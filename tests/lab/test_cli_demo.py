"""`zenoh-robot demo` interrupted by Ctrl-C: GCS, companion and simulator stop in order and the summary
is still printed (the `make demo` path)."""
from __future__ import annotations

import os
import signal
import subprocess
import time

from cli_helpers import INTERACTIVE_CLI, ROOT
from conftest import Lines
from conftest import kill_process as _stop


def test_ctrl_c_stops_the_demo_in_order_and_prints_the_summary():
    proc = subprocess.Popen([*INTERACTIVE_CLI, "demo", "--duration", "45"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True,
                            env=dict(os.environ, COLUMNS="200", PYTHONUNBUFFERED="1"))
    try:
        out = Lines(proc)
        assert out.wait_for(r"^demo: simulator, companion and GCS on localhost", 20.0), out.text()
        # flying: the GCS's mission says so once the climb is done (not a fixed wait)
        assert out.wait_for(r"flying the \S+ pattern", 40.0), out.text()
        assert proc.poll() is None, out.text()        # --duration 45: still running, Ctrl-C ends it
        os.killpg(proc.pid, signal.SIGINT)            # the terminal's Ctrl-C: the whole foreground group
        rc = proc.wait(timeout=45)
        time.sleep(0.2)                               # the reader thread takes the last lines
        text = out.text()
        assert rc == 130, text                         # interrupted: not "it did its job"
        assert "demo: interrupted; stopping (GCS, then companion, then simulator)" in text
        # The GCS, stopped mid-flight, says what the drone is doing now and how to land it.
        assert "interrupted by the operator: " in text and "gcs cmd" in text, text
        assert "demo summary" in text and "setpoint ->" in text and "sensor <-" in text, text
        assert "no summary" not in text and "Traceback" not in text, text
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        _stop(proc)
