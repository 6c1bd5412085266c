"""The companion names what it sheds (issue #42): a camera that cannot keep the rate asked raises one
``shedding`` event per episode, ends it when the rate is back, and the summary counts the frames short.
The watch is driven with its own clock and counters: no process, no timing. And the camera gives way by its
thread's own OS priority (companion/priority.py), read back from the kernel."""
from __future__ import annotations

import os
import threading

import pytest

from companion.priority import MAX_NICE, lower_thread_priority
from companion.shedding import PERIOD_S, CameraShedding

pytestmark = pytest.mark.fast


class Events:
    def __init__(self) -> None:
        self.got: list[tuple[str, str, str]] = []

    def event(self, kind: str, detail: str, action: str = "") -> None:
        self.got.append((kind, detail, action))


def test_a_camera_behind_is_named_once_an_episode_and_cleared() -> None:
    sent, rate, events = [0], [30.0], Events()
    watch = CameraShedding(lambda: sent[0], lambda: rate[0], events)
    t = 100.0
    watch.check(t)                         # no frame yet: a camera still opening is not judged
    sent[0] = 1
    watch.check(t)                         # the first frame starts the window
    for n in (150, 150):                   # two full windows at 30 fps: nothing said
        t += PERIOD_S
        sent[0] += n
        watch.check(t)
    assert events.got == []
    for n in (60, 70):                     # two windows far short: said once
        t += PERIOD_S
        sent[0] += n
        watch.check(t)
    assert [(k, a) for k, _, a in events.got] == [("shedding", "camera frames skipped")]
    assert events.got[0][1].startswith("camera: 60 of 150 frames in 5 s (asked 30 fps)")
    t += PERIOD_S
    sent[0] += 149                         # back (one late tick is not behind)
    watch.check(t)
    assert [a for _, _, a in events.got] == ["camera frames skipped", "cleared"]
    assert watch.summary() == {"camera_windows_short": 2, "camera_frames_short": 170}


def test_a_rate_raised_live_starts_the_window_again() -> None:
    sent, rate, events = [1], [15.0], Events()
    watch = CameraShedding(lambda: sent[0], lambda: rate[0], events)
    t = 0.0
    watch.check(t)
    t += PERIOD_S / 2
    sent[0] += 37
    rate[0] = 30.0                         # a GCS's downlink: judged at 30 fps from now only
    watch.check(t)
    t += PERIOD_S
    sent[0] += 150
    watch.check(t)
    assert events.got == [] and watch.summary()["camera_windows_short"] == 0


def test_the_camera_thread_gives_way_by_its_own_nice_value_and_no_other_thread_does() -> None:
    """Linux keeps a nice value per thread: the camera's is raised, the caller's (the setpoint path's) is not."""
    base = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    got: list[int | None] = []
    seen: list[int] = []

    def camera() -> None:
        got.append(lower_thread_priority(10))
        seen.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
    th = threading.Thread(target=camera)
    th.start()
    th.join()
    assert got == [min(MAX_NICE, base + 10)] and seen == got
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base     # this thread untouched
    assert os.getpriority(os.PRIO_PROCESS, os.getpid()) == base                    # nor the process's main


def test_a_streaming_camera_runs_at_the_lowered_priority() -> None:
    import time

    from companion.camera_streamer import CAMERA_NICE, CameraStreamer
    from companion.config import CompanionConfig
    from zenoh_robot import Node, qos
    from zenoh_robot.tools.stream_metrics import StreamRecorder

    base = os.getpriority(os.PRIO_PROCESS, os.getpid())
    cfg = CompanionConfig(camera="test", camera_rate_hz=20.0)
    with Node("camera_nice", namespace=f"cn{os.getpid()}") as node:
        cam = CameraStreamer(node, "image", qos.IMAGE, lambda: cfg, StreamRecorder(), StreamRecorder())
        cam.start()
        try:
            deadline = time.monotonic() + 20.0
            while cam.frames_sent < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert cam.frames_sent >= 2
            assert cam._thread is not None and cam._thread.native_id is not None
            assert os.getpriority(os.PRIO_PROCESS, cam._thread.native_id) == min(MAX_NICE, base + CAMERA_NICE)
            assert cam.nice == min(MAX_NICE, base + CAMERA_NICE)
        finally:
            cam.close()
