"""Matched but silent (issue #42): a subscription whose matched publisher sends nothing raises
``silent_stream`` once, and once more (``silent`` False) when samples come; nothing while unmatched."""
from __future__ import annotations

import threading

import pytest
from conftest import spinning_nodes, wait_for

from zenoh_robot import QoSProfile, SubscriptionEventCallbacks
from zenoh_robot.events import SilentStreamInfo
from zenoh_robot.msgs import String
from zenoh_robot.silence import DEFAULT_WINDOW_S, MIN_WINDOW_S, SilenceWatch, silence_window

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def test_a_matched_publisher_that_never_puts_is_a_silent_stream_until_it_does(ns: str) -> None:
    with spinning_nodes(ns) as (talker, listener):
        got: list[SilentStreamInfo] = []
        received: list[str] = []
        sub = listener.create_subscription(String, "chatter", lambda m: received.append(m.data), QoSProfile(depth=10),
                                           event_callbacks=SubscriptionEventCallbacks(silent_stream=got.append))
        sub.events.expected_period_s = 0.1        # silence: 5 periods, floored at MIN_WINDOW_S
        pub = talker.create_publisher(String, "chatter", QoSProfile(depth=10))
        assert wait_for(lambda: sub.get_publisher_count() == 1, 10.0)
        assert wait_for(lambda: len(got) == 1, 10.0), got
        first = got[0]
        assert first.silent and first.publishers == 1 and not first.ever_received and first.total_count == 1
        assert first.window_s == MIN_WINDOW_S
        assert "publisher seen, 0 samples in" in first.describe("/x/chatter")
        assert wait_for(lambda: False, 0.5) is False and len(got) == 1   # once, not once per tick
        pub.publish(String("hello"))
        assert wait_for(lambda: len(got) == 2, 10.0), got
        assert not got[1].silent and received == ["hello"]
        assert "samples again" in got[1].describe("/x/chatter")


def test_no_publisher_no_silence_event_and_no_callback_no_watch(ns: str) -> None:
    with spinning_nodes(ns) as (_talker, listener):
        got: list[SilentStreamInfo] = []
        sub = listener.create_subscription(String, "nobody", lambda m: None, QoSProfile(depth=10),
                                           event_callbacks=SubscriptionEventCallbacks(silent_stream=got.append))
        sub.events.expected_period_s = 0.1
        plain = listener.create_subscription(String, "plain", lambda m: None, QoSProfile(depth=10))
        assert plain.events.expected_period_s is None    # no callback: not watched
        assert wait_for(lambda: bool(got), 1.5) is False


def test_the_watch_compares_clocks_only() -> None:
    w = SilenceWatch(1.0)
    assert w.check(10.0, 0, None, None) is None                  # nobody matched
    assert w.check(10.5, 1, 10.0, None) is None                  # matched, not yet silent
    ev = w.check(11.0, 1, 10.0, None)
    assert ev is not None and ev.silent and ev.for_s == 1.0
    assert w.check(12.0, 1, 10.0, None) is None                  # once per episode
    back = w.check(12.5, 1, 10.0, 12.2)
    assert back is not None and not back.silent
    assert w.check(13.1, 1, 10.0, 12.2) is None                  # the window restarts from the last sample
    again = w.check(13.3, 1, 10.0, 12.2)
    assert again is not None and again.silent and again.ever_received and again.total_count == 2
    assert silence_window(None, None) == DEFAULT_WINDOW_S
    assert silence_window(0.5, None) == 2.5 and silence_window(None, 0.001) == MIN_WINDOW_S


def test_a_subscription_whose_declaration_went_missing_recovers_by_declaring_again(ns: str) -> None:
    """The graph shows the publisher matched, but Zenoh's subscriber is gone (a declaration that never reached
    the publisher's side, issue #42's silent sensor): the silence event declares the subscriber again, says
    so, and the stream comes back by itself."""
    with spinning_nodes(ns) as (talker, listener):
        got: list[SilentStreamInfo] = []
        received: list[str] = []
        sub = listener.create_subscription(String, "chatter", lambda m: received.append(m.data), QoSProfile(depth=10),
                                           event_callbacks=SubscriptionEventCallbacks(silent_stream=got.append))
        sub.events.expected_period_s = 0.1
        pub = talker.create_publisher(String, "chatter", QoSProfile(depth=10))
        assert wait_for(lambda: sub.get_publisher_count() == 1, 10.0)
        pub.publish(String("before"))
        assert wait_for(lambda: received == ["before"], 10.0), received
        sub._zsub.undeclare()      # the Zenoh subscriber lost; the graph token stays
        stop = threading.Event()

        def talk() -> None:        # the publisher goes on at 20 Hz, as a drone's stream does
            while not stop.wait(0.05):
                pub.publish(String("again"))
        th = threading.Thread(target=talk, daemon=True)
        th.start()
        try:
            assert wait_for(lambda: bool(got), 10.0), got
            assert got[0].silent and got[0].redeclared and got[0].ever_received, got
            assert "subscription declared again" in got[0].describe("/x/chatter") and sub.redeclared == 1
            assert wait_for(lambda: "again" in received, 10.0), received
            assert wait_for(lambda: len(got) == 2 and not got[1].silent, 10.0), got
        finally:
            stop.set()
            th.join()
