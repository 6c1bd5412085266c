"""What the companion itself sheds, named (issue #42): its camera falling behind the rate asked.

The camera thread holds its rate by the schedule (camera.RateKeeper); a companion short of CPU encodes
fewer frames than asked, and the GCS would see only a lower fps. Every ``PERIOD_S`` the frames sent are
compared with the rate in force; a window under ``SHORT`` of it raises a ``shedding`` event once per
episode ("camera: 61 of 150 frames in 5 s (asked 30 fps): this companion cannot keep up ..."), a full
window ends it, and the summary keeps the frames short in all. The setpoint path is never shed: it runs
on the executor, the camera on its own thread, and an encoder that cannot keep up gives way, not the
setpoints.

Runs on the executor (the watchdog's timer); reads the camera's frame count as a plain int.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

PERIOD_S = 5.0
SHORT = 0.9      # under 90 % of the frames asked: behind (a start-up window or one late tick stays above)


class CameraShedding:
    def __init__(self, frames_sent: Callable[[], int], rate_hz: Callable[[], float], events: Any) -> None:
        self._frames_sent, self._rate_hz, self._events = frames_sent, rate_hz, events
        self._at = time.monotonic()
        self._sent = frames_sent()
        self._rate = rate_hz()
        self._raised = False
        self.windows_short = 0
        self.frames_short = 0    # frames asked but not sent, over the windows that fell short

    def check(self, now: float) -> None:
        sent, rate = self._frames_sent(), self._rate_hz()
        if sent == 0 or rate != self._rate:
            # Judged from the first frame (a camera still opening is not behind) and over one rate only (a
            # GCS's downlink changes it live): the window starts again.
            self._at, self._sent, self._rate = now, sent, rate
            return
        if now - self._at < PERIOD_S:
            return
        window = now - self._at
        got, asked = sent - self._sent, rate * window
        self._at, self._sent = now, sent
        if asked >= 1 and got < SHORT * asked:
            self.windows_short += 1
            self.frames_short += int(asked - got)
            if not self._raised:
                self._raised = True
                self._events.event("shedding", f"camera: {got} of {asked:.0f} frames in {window:.0f} s (asked "
                                   f"{rate:g} fps): this companion cannot encode that fast; setpoints "
                                   "and state keep their rate, the camera gives way", "camera frames skipped")
        elif self._raised:
            self._raised = False
            self._events.event("shedding", f"camera: back to {got / window:.1f} fps ({self.frames_short} frames "
                               "skipped in all)", "cleared")

    def summary(self) -> dict[str, int]:
        return {"camera_windows_short": self.windows_short, "camera_frames_short": self.frames_short}
