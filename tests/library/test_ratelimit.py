"""The one rate limiter (library and px4_link twin): bounded by keys, and a full table frees only
windows that ended with nothing to say, so a forged key never gets a fresh budget early."""
from __future__ import annotations

import pytest

import px4_link.ratelimit as px4_rl
import zenoh_robot.ratelimit as lib_rl

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(params=[lib_rl, px4_rl], ids=["library", "px4_link"])
def limiter(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> tuple[object, Clock]:
    clock = Clock()
    monkeypatch.setattr(request.param.time, "monotonic", clock)
    lim = request.param.RateLimiter(burst=1, interval=2.0)
    lim.MAX_KEYS = 4
    return lim, clock


def test_a_full_table_refuses_new_keys_while_every_window_is_live(limiter: tuple[object, Clock]) -> None:
    lim, clock = limiter
    for i in range(4):
        assert lim.admit(f"k{i}") is not None
    assert lim.admit("forged") is None and lim.overflow == 1
    clock.t += 1.0                     # windows still live: nothing may be freed
    assert lim.admit("forged2") is None and lim.overflow == 2


def test_a_full_table_frees_ended_windows_with_nothing_suppressed(limiter: tuple[object, Clock]) -> None:
    lim, clock = limiter
    for i in range(4):
        lim.admit(f"k{i}")
    lim.admit("k0")                    # k0 has a suppressed line pending: it must survive the sweep
    clock.t += 2.5
    assert lim.admit("new") is not None
    assert len(lim._windows) == 2      # k1..k3 ended silent and went; k0 and the new key stay
    again = lim.admit("k0")
    assert again is not None and again.suppressed == 1 and again.count == 3


def test_a_flood_of_live_keys_is_swept_at_most_four_times_per_interval(limiter: tuple[object, Clock]) -> None:
    lim, clock = limiter
    for i in range(4):
        lim.admit(f"k{i}")
    clock.t += 2.5
    assert lim.admit("a") is not None                 # sweeps k0..k3
    for i in range(3):
        lim.admit(f"b{i}")
    assert lim.admit("c") is None                     # full of live windows; swept a moment ago
    clock.t += 0.1
    assert lim.admit("d") is None and lim.overflow == 2
