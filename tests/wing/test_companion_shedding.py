"""The companion names what it sheds (issue #42): a camera that cannot keep the rate asked raises one
``shedding`` event per episode, ends it when the rate is back, and the summary counts the frames short.
The watch is driven with its own clock and counters: no process, no timing."""
from __future__ import annotations

import pytest

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
