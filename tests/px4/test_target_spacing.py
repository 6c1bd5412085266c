"""The step rule of px4_link's TargetValidator judges a stream by its sender's spacing when the targets
carry it: after a fade, a lossy link delivers the next target milliseconds after the last one before the
fade, and a square flown at 2 m/s was refused as 12 m/s (a bursty 50 % flight's failure). A target that
really jumps is still refused, and a sender's stamps never buy more than one second of travel."""
from __future__ import annotations

import pytest

from px4_link.targets import PositionTarget, TargetRefused, TargetValidator

pytestmark = pytest.mark.fast


def test_a_stream_after_a_fade_is_judged_by_the_time_between_its_targets_as_sent() -> None:
    v = TargetValidator(max_speed=10.0)
    v.accept(PositionTarget(0.0, 0.0, -5.0), now=100.0, sent_at=50.0)
    after_fade = PositionTarget(0.6, 0.0, -5.0)              # 300 ms at 2 m/s, arriving 50 ms later
    with pytest.raises(TargetRefused, match="too_fast|jumps"):
        v.check(after_fade, now=100.05)                        # by arrival alone: 12 m/s
    v.check(after_fade, now=100.05, sent_at=50.3)              # as sent: 2 m/s
    with pytest.raises(TargetRefused):
        v.check(PositionTarget(6.0, 0.0, -5.0), now=100.05, sent_at=50.3)     # a real jump: 20 m/s
    with pytest.raises(TargetRefused):                         # stamps a day apart buy one second at most
        v.check(PositionTarget(15.0, 0.0, -5.0), now=100.05, sent_at=50.0 + 86400)
    v.check(PositionTarget(9.0, 0.0, -5.0), now=100.05, sent_at=50.0 + 86400)
