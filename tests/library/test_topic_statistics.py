"""Topic statistics over real Zenoh sessions: age, period, empty windows, node-wide, recording.

Bounds are loose on purpose: the machine is shared, so timing only has to be plausible.
"""
from __future__ import annotations

import json
import math
import threading
from typing import Any

import pytest
from conftest import linked_configs, spinning_nodes, wait_for
from stats_helpers import Stream, collect_windows, matched

from zenoh_robot import Node, QoSProfile
from zenoh_robot.msgs import Header, Setpoint, StatisticsEntry, String, TopicStatistics
from zenoh_robot.tools.recorder import COLUMNS, StatisticsRecorder
from zenoh_robot.topic_statistics import TopicStatisticsCollector, TopicStatisticsOptions, default_statistics_key

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

RELIABLE = QoSProfile(reliability="reliable", depth=50)


@pytest.fixture
def pair(ns: str):
    """(talker, listener), linked over loopback, both spinning in background threads."""
    with spinning_nodes(ns) as nodes:
        yield nodes


def _is_empty(e: StatisticsEntry) -> bool:
    return (e.sample_count == 0 and math.isnan(e.average) and math.isnan(e.minimum)
            and math.isnan(e.maximum) and math.isnan(e.std_dev))


def _consistent(e: StatisticsEntry) -> None:
    assert e.sample_count > 0
    assert not math.isnan(e.average)
    assert e.minimum <= e.average <= e.maximum
    assert e.std_dev >= 0


def test_rate_stream_gives_period_age_and_publishes_on_default_key(pair, ns: str) -> None:
    a, b = pair
    sub = b.create_subscription(Setpoint, "setpoint", lambda m: None, RELIABLE,
                                topic_statistics=TopicStatisticsOptions(window=0.5))
    assert isinstance(sub.statistics, TopicStatisticsCollector)
    assert sub.statistics.topic == f"{ns}/statistics/setpoint"
    windows = collect_windows(sub)
    remote: list[TopicStatistics] = []
    # A third subscription, in the other session, on the default name derived the same way.
    stats_sub = a.create_subscription(TopicStatistics, "statistics/setpoint", remote.append, RELIABLE)
    assert stats_sub.statistics is None   # statistics of statistics are never collected
    pub = a.create_publisher(Setpoint, "setpoint", RELIABLE)
    matched(pub, sub)
    matched(sub.statistics.publisher, stats_sub)

    def full() -> list[TopicStatistics]:
        return [w for w in windows if w.message_period_ms.sample_count >= 10]

    with Stream(pub, lambda: Setpoint(header=Header.now(), x=1.0), 50.0):
        assert wait_for(lambda: len(full()) >= 2, 8.0), [w.message_period_ms for w in windows]
    w = full()[-1]
    assert 10.0 <= w.message_period_ms.average <= 60.0, w.message_period_ms
    _consistent(w.message_period_ms)
    _consistent(w.message_age_ms)
    assert w.message_age_ms.average < 1000.0       # same host: stamps are close
    assert w.topic == f"/{ns}/setpoint"
    assert w.node == f"/{ns}/listener"
    assert 0 < w.window_start < w.window_stop
    assert 0.2e9 < w.window_stop - w.window_start < 3e9
    assert w.received >= w.message_period_ms.sample_count
    assert sub.statistics.last is not None and sub.statistics.last.window_stop >= w.window_stop
    assert wait_for(lambda: any(r.message_period_ms.sample_count >= 10 for r in remote), 5.0)
    r = next(r for r in remote if r.message_period_ms.sample_count >= 10)
    assert r.topic == f"/{ns}/setpoint" and r.node == f"/{ns}/listener"


def test_unstamped_header_gives_no_age_but_a_period(pair) -> None:
    a, b = pair
    sub = b.create_subscription(Setpoint, "unstamped", lambda m: None, RELIABLE,
                                topic_statistics=TopicStatisticsOptions(window=0.3))
    windows = collect_windows(sub)
    pub = a.create_publisher(Setpoint, "unstamped", RELIABLE)
    matched(pub, sub)
    with Stream(pub, lambda: Setpoint(x=2.0), 50.0):   # Header() has stamp 0: "not stamped"
        assert wait_for(lambda: any(w.message_period_ms.sample_count >= 3 for w in windows), 6.0)
    w = next(w for w in windows if w.message_period_ms.sample_count >= 3)
    assert _is_empty(w.message_age_ms), w.message_age_ms
    _consistent(w.message_period_ms)


def test_type_without_header_uses_envelope_stamp(pair) -> None:
    a, b = pair
    sub = b.create_subscription(String, "chatter", lambda m: None, RELIABLE,
                                topic_statistics=TopicStatisticsOptions(window=0.3))
    windows = collect_windows(sub)
    pub = a.create_publisher(String, "chatter", RELIABLE)
    matched(pub, sub)
    with Stream(pub, lambda: String("hi"), 50.0):
        assert wait_for(lambda: any(w.message_age_ms.sample_count >= 3 for w in windows), 6.0)
    w = next(w for w in windows if w.message_age_ms.sample_count >= 3)
    _consistent(w.message_age_ms)
    assert w.message_age_ms.average < 1000.0


def test_first_sample_alone_has_no_period(pair) -> None:
    a, b = pair
    sub = b.create_subscription(Setpoint, "once", lambda m: None, RELIABLE,
                                topic_statistics=TopicStatisticsOptions(window=0.2))
    windows = collect_windows(sub)
    pub = a.create_publisher(Setpoint, "once", RELIABLE)
    matched(pub, sub)
    pub.publish(Setpoint(header=Header.now()))
    assert wait_for(lambda: any(w.message_age_ms.sample_count for w in windows), 5.0)
    w = next(w for w in windows if w.message_age_ms.sample_count)
    assert w.message_age_ms.sample_count == 1
    assert w.message_age_ms.std_dev == 0.0
    assert w.message_age_ms.minimum == w.message_age_ms.average == w.message_age_ms.maximum
    assert _is_empty(w.message_period_ms), w.message_period_ms
    assert w.received == 1


def test_empty_window_after_publisher_stops(pair) -> None:
    a, b = pair
    sub = b.create_subscription(Setpoint, "stops", lambda m: None, RELIABLE,
                                topic_statistics=TopicStatisticsOptions(window=0.2))
    windows = collect_windows(sub)
    pub = a.create_publisher(Setpoint, "stops", RELIABLE)
    matched(pub, sub)
    with Stream(pub, lambda: Setpoint(header=Header.now()), 50.0) as stream:
        assert wait_for(lambda: any(w.message_period_ms.sample_count >= 3 for w in windows), 6.0)
    assert wait_for(lambda: sub.counters.received >= stream.sent, 3.0)
    n = len(windows)
    assert wait_for(lambda: len(windows) >= n + 2, 5.0)
    last = windows[-1]
    assert _is_empty(last.message_age_ms) and _is_empty(last.message_period_ms), last
    assert last.received == stream.sent     # the cumulative counters do carry over
    assert any(not math.isnan(w.message_period_ms.average) for w in windows[:n])

    # After a silence the first new sample has a period (the previous arrival carries over).
    pub.publish(Setpoint(header=Header.now()))
    assert wait_for(lambda: any(w.received > stream.sent for w in windows), 5.0)
    w = next(w for w in windows if w.received > stream.sent)
    assert w.message_period_ms.sample_count == 1 and w.message_period_ms.average >= 200.0


def test_node_wide_statistics_with_custom_topic(ns: str) -> None:
    listen, connect = linked_configs()
    opts = TopicStatisticsOptions(window=0.3, topic="stats_all")
    with Node("listener", namespace=ns, config=listen, enable_topic_statistics=opts) as b, \
            Node("talker", namespace=ns, config=connect) as a:
        threads = [threading.Thread(target=n.spin, daemon=True) for n in (a, b)]
        for t in threads:
            t.start()
        s1 = b.create_subscription(Setpoint, "setpoint", lambda m: None, RELIABLE)
        s2 = b.create_subscription(String, "chatter", lambda m: None, RELIABLE)
        off = b.create_subscription(String, "quiet", lambda m: None, RELIABLE, topic_statistics=False)
        raw = b.create_subscription(TopicStatistics, "other_stats", lambda m: None, RELIABLE)
        assert s1.statistics is not None and s2.statistics is not None
        assert off.statistics is None and raw.statistics is None
        assert s1.statistics.topic == s2.statistics.topic == f"{ns}/stats_all"
        assert s1.statistics.options.window == 0.3

        rec = StatisticsRecorder.subscribe(a, "stats_all")   # the other session, relative name
        p1 = a.create_publisher(Setpoint, "setpoint", RELIABLE)
        p2 = a.create_publisher(String, "chatter", RELIABLE)
        matched(p1, s1)
        matched(p2, s2)
        matched(s1.statistics.publisher, rec.subscription)

        def seen() -> set[str]:
            return {r["topic"] for r in rec.rows if r["period_count"] > 0}

        with Stream(p1, lambda: Setpoint(header=Header.now()), 50.0), Stream(p2, lambda: String("x"), 50.0):
            assert wait_for(lambda: seen() >= {f"/{ns}/setpoint", f"/{ns}/chatter"}, 8.0), rec.rows[-4:]
        assert all(r["node"] == f"/{ns}/listener" for r in rec.rows)
        rec.close()
        assert rec.subscription is None

        # destroy: idempotent, takes its publisher away, and the subscription keeps working.
        collector = s1.statistics
        collector.destroy()
        collector.destroy()
        assert collector.closed and collector.publisher not in b.publishers
        assert collector._on_sample not in s1.sample_hooks
    for t in threads:
        t.join(timeout=2.0)
    s2.statistics.destroy()   # after the node closed: still fine


def test_bad_options_are_refused(ns: str) -> None:
    for bad in (0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="window"):
            TopicStatisticsOptions(window=bad)
    with pytest.raises(TypeError, match="window"):
        TopicStatisticsOptions(window="1")   # type: ignore[arg-type]
    with pytest.raises(ValueError, match="topic"):
        TopicStatisticsOptions(topic="")
    listen, _ = linked_configs()
    with Node("n", namespace=ns, config=listen) as node:
        with pytest.raises(TypeError, match="TopicStatisticsOptions"):
            node.create_subscription(String, "x", lambda m: None, topic_statistics="yes")
        assert node.subscriptions == []
        with pytest.raises(ValueError):   # InvalidNameError
            node.create_subscription(String, "x", lambda m: None,
                                     topic_statistics=TopicStatisticsOptions(topic="bad//name"))
        assert node.subscriptions == [] and node.publishers == []
        quiet = node.create_subscription(String, "y", lambda m: None,
                                         topic_statistics=TopicStatisticsOptions(window=5, publish=False))
        assert quiet.statistics.publisher is None and node.publishers == []


def test_default_statistics_key() -> None:
    assert default_statistics_key("uav1", "uav1/setpoint") == "uav1/statistics/setpoint"
    assert default_statistics_key("", "chatter") == "statistics/chatter"
    assert default_statistics_key("uav1", "gcs/cmd") == "uav1/statistics/gcs/cmd"
    assert default_statistics_key("uav1", "uav10/x") == "uav1/statistics/uav10/x"


def _stats(i: int, *, age: bool = True) -> TopicStatistics:
    entry = StatisticsEntry(average=1.5 + i, minimum=1.0, maximum=2.0 + i, std_dev=0.25, sample_count=4)
    return TopicStatistics(topic="/uav1/setpoint", node="/uav1/listener", window_start=10**18 + i,
                           window_stop=10**18 + i + 500_000_000,
                           message_age_ms=entry if age else StatisticsEntry(), message_period_ms=entry,
                           received=10 * i, lost=i, dropped=0)


def _same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return a.keys() == b.keys() and all(
        (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) or a[k] == b[k] for k in a)


def test_recorder_round_trips_csv_and_json_with_nan(tmp_path) -> None:
    rec = StatisticsRecorder()
    rec.record(_stats(0))
    rec.record(_stats(1, age=False))
    rows = rec.rows
    assert list(rows[0]) == list(COLUMNS)
    assert math.isnan(rows[1]["age_avg_ms"]) and rows[1]["age_count"] == 0

    csv_path = rec.save_csv(tmp_path / "deep" / "dir" / "stats.csv")   # parents are created
    assert "nan" in csv_path.read_text().splitlines()[2]
    back = StatisticsRecorder.load_csv(csv_path)
    assert len(back) == 2 and all(_same(x, y) for x, y in zip(rows, back, strict=True))

    json_path = rec.save_json(tmp_path / "stats.json")
    doc = json.loads(json_path.read_text())    # strict JSON: no NaN token
    assert doc["rows"][1]["age_avg_ms"] is None and doc["rows"][0]["age_avg_ms"] == 1.5
    assert doc["columns"] == list(COLUMNS) and doc["dropped_rows"] == 0
    back = StatisticsRecorder.load_json(json_path)
    assert all(_same(x, y) for x, y in zip(rows, back, strict=True))
    assert not list(tmp_path.glob("**/*.tmp"))


def test_recorder_bound_and_bad_input(tmp_path) -> None:
    rec = StatisticsRecorder(max_rows=3)
    for i in range(5):
        rec.record(_stats(i))
    assert len(rec) == 3 and rec.dropped_rows == 2
    assert [r["window_start"] for r in rec.rows] == [10**18, 10**18 + 1, 10**18 + 2]   # keeps the first
    assert json.loads(rec.save_json(tmp_path / "s.json").read_text())["dropped_rows"] == 2

    with pytest.raises(ValueError, match="max_rows"):
        StatisticsRecorder(max_rows=0)
    with pytest.raises(TypeError, match="TopicStatistics"):
        rec.record(String("no"))   # type: ignore[arg-type]
    with pytest.raises(IsADirectoryError, match=str(tmp_path)):
        rec.save_csv(tmp_path)
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OSError, match="file"):
        rec.save_json(blocker / "sub" / "s.json")   # a parent that is a file
    (tmp_path / "junk.json").write_text('{"rows": [{"topic": "x"}]}')
    with pytest.raises(ValueError, match="missing column"):
        StatisticsRecorder.load_json(tmp_path / "junk.json")

    # Thread-safe: concurrent writers never exceed the bound nor lose the count.
    rec = StatisticsRecorder(max_rows=500)
    workers = [threading.Thread(target=lambda: [rec.record(_stats(1)) for _ in range(200)]) for _ in range(4)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert len(rec) == 500 and rec.dropped_rows == 300
