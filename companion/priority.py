"""The camera gives way by the operating system's own rule, not only by its schedule (issue #42).

On a companion computer short of CPU (a Pi encoding 30 fps, or a test machine running ten drones) the
camera thread competes with the threads that forward setpoints and publish state, and with every other
process. ``lower_thread_priority`` raises the calling thread's nice value: Linux keeps a nice value per
thread (setpriority on the thread's id; POSIX says per process, NPTL says per thread), so the scheduler
runs the setpoint path first and the encoder with what is left. Raising one's own nice value needs no
privilege; where it is not possible (another OS, a sandbox) the camera runs as before and the caller says so.
"""
from __future__ import annotations

import os
import threading

MAX_NICE = 19


def lower_thread_priority(step: int) -> int | None:
    """Raise the calling thread's nice value by ``step`` (capped at 19); its new value, None if not possible."""
    try:
        tid = threading.get_native_id()
        nice = min(MAX_NICE, os.getpriority(os.PRIO_PROCESS, tid) + step)
        os.setpriority(os.PRIO_PROCESS, tid, nice)
        return nice
    except (AttributeError, OSError):
        return None
