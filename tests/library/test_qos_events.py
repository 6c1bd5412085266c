"""QoS policies and events: durability, deadline, lifespan, liveliness, compatibility, message lost.

Real Zenoh sessions over loopback; a policy about processes (liveliness on SIGKILL)
is tested against a real child process.
"""
from __future__ import annotations

import signal
import textwrap
import threading
import time
from typing import Any

import msgpack
import pytest
from conftest import linked_configs, linked_nodes, python_proc, wait_for

from zenoh_robot import Node, QoSProfile, envelope
from zenoh_robot.events import PublisherEventCallbacks, SubscriptionEventCallbacks
from zenoh_robot.message import type_support
from zenoh_robot.msgs import Float32, String
from zenoh_robot.qos_compat import PolicyKind

BE = QoSProfile(reliability="best_effort", depth=10)


@pytest.fixture
def pair(ns: str):
    with linked_nodes(ns, links=1) as nodes:
        yield nodes


class Events:
    """Collects every event by kind, noting the thread it ran on."""

    def __init__(self) -> None:
        self.by_kind: dict[str, list[Any]] = {}
        self.threads: set[str] = set()
        self._lock = threading.Lock()

    def cb(self, kind: str):
        def record(status: Any) -> None:
            with self._lock:
                self.by_kind.setdefault(kind, []).append(status)
                self.threads.add(threading.current_thread().name)
        return record

    def get(self, kind: str) -> list[Any]:
        with self._lock:
            return list(self.by_kind.get(kind, []))

    def sub_callbacks(self) -> SubscriptionEventCallbacks:
        return SubscriptionEventCallbacks(**{k: self.cb(k) for k in (
            "deadline", "liveliness", "incompatible_qos", "message_lost", "incompatible_type", "matched")})

    def pub_callbacks(self) -> PublisherEventCallbacks:
        return PublisherEventCallbacks(**{k: self.cb(k) for k in (
            "deadline", "liveliness", "incompatible_qos", "incompatible_type", "matched")})


def spin_both(a: Node, b: Node, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        a.spin_once(0.005)
        b.spin_once(0.005)


# -- durability ------------------------------------------------------------------------
@pytest.mark.parametrize("history,depth,expected", [("keep_last", 3, ["2", "3", "4"]),
                                                    ("keep_all", 0, ["0", "1", "2", "3", "4"])])
def test_late_joiner_gets_kept_samples_on_transient_local_and_none_on_volatile(pair, history, depth, expected):
    a, b = pair
    tl = QoSProfile(durability="transient_local", history=history, depth=depth)
    pub = a.create_publisher(String, "config", tl)
    for i in range(5):
        pub.publish(String(str(i)))
    time.sleep(0.3)
    late: list[str] = []
    volatile: list[str] = []
    b.create_subscription(String, "config", lambda m: late.append(m.data), tl)
    b.create_subscription(String, "config", lambda m: volatile.append(m.data), QoSProfile(depth=10))
    assert b.spin_until(lambda: len(late) >= len(expected), 5.0), late
    b.spin(timeout=0.3)
    assert late == expected
    assert volatile == []
    pub.publish(String("live"))
    assert b.spin_until(lambda: volatile == ["live"] and late[-1] == "live", 3.0), (late, volatile)
    assert late.count("live") == 1


# -- deadline --------------------------------------------------------------------------
def test_deadline_missed_on_both_sides_only_when_the_stream_stops(pair):
    a, b = pair
    pub_events, sub_events = Events(), Events()
    q = BE.replace(deadline=0.2)
    pub = a.create_publisher(Float32, "hb", q, event_callbacks=pub_events.pub_callbacks())
    got: list[float] = []
    b.create_subscription(Float32, "hb", lambda m: got.append(m.data), q, event_callbacks=sub_events.sub_callbacks())
    spin_both(a, b, 0.5)
    assert sub_events.get("deadline") == [] and pub_events.get("deadline") == []   # no samples yet: no instance
    for _ in range(16):                       # 20 Hz for 0.8 s: well inside a 200 ms deadline
        pub.publish(Float32(1.0))
        spin_both(a, b, 0.05)
    assert got, "nothing arrived"
    assert sub_events.get("deadline") == [] and pub_events.get("deadline") == []
    spin_both(a, b, 0.75)                     # silence: about three periods
    subs, pubs = sub_events.get("deadline"), pub_events.get("deadline")
    assert subs and pubs, (subs, pubs)
    assert 2 <= subs[-1].total_count <= 5 and 2 <= pubs[-1].total_count <= 5
    assert sum(s.total_count_change for s in subs) == subs[-1].total_count
    assert sub_events.threads <= {"MainThread"}   # events run on the executor (here: the test's spin)


# -- lifespan --------------------------------------------------------------------------
def test_samples_older_than_the_publishers_lifespan_are_dropped_and_counted(pair):
    a, b = pair
    got: list[float] = []
    sub = b.create_subscription(Float32, "short", lambda m: got.append(m.data), BE)
    pub = a.create_publisher(Float32, "short", BE.replace(lifespan=0.1))
    assert wait_for(lambda: sub.get_publisher_count() == 1, 5.0)
    for i in range(3):
        pub.publish(Float32(float(i)))
    time.sleep(0.4)                            # not spinning: they age past the lifespan in the queue
    b.spin(timeout=0.2)
    assert got == [] and sub.counters.expired == 3
    pub.publish(Float32(9.0))
    assert b.spin_until(lambda: got == [9.0], 3.0)


# -- liveliness ------------------------------------------------------------------------
def test_manual_liveliness_lost_and_regained_on_both_sides(pair):
    a, b = pair
    pub_events, sub_events = Events(), Events()
    q = BE.replace(liveliness="manual_by_topic", liveliness_lease_duration=0.3)
    pub = a.create_publisher(String, "alive", q, event_callbacks=pub_events.pub_callbacks())
    b.create_subscription(String, "alive", lambda m: None, q, event_callbacks=sub_events.sub_callbacks())
    for _ in range(10):                       # asserting every 100 ms: alive, nothing lost
        pub.assert_liveliness()
        spin_both(a, b, 0.1)
    changed = sub_events.get("liveliness")
    assert changed and changed[-1].alive_count == 1 and changed[-1].not_alive_count == 0, changed
    assert len(changed) == 1 and pub_events.get("liveliness") == []
    spin_both(a, b, 0.8)                      # stops asserting
    changed = sub_events.get("liveliness")
    assert changed[-1].alive_count == 0 and changed[-1].not_alive_count == 1, changed
    assert changed[-1].alive_count_change == -1 and changed[-1].not_alive_count_change == 1
    lost = pub_events.get("liveliness")
    assert len(lost) == 1 and lost[0].total_count == 1 and lost[0].total_count_change == 1
    pub.publish(String("back"))               # a sample asserts too
    spin_both(a, b, 0.3)
    assert sub_events.get("liveliness")[-1].alive_count == 1


PUBLISHER_CHILD = textwrap.dedent("""
    import sys, time
    from zenoh_robot import Node, QoSProfile, SessionConfig
    from zenoh_robot.msgs import String
    cfg = SessionConfig(listen=[], connect=sys.argv[1].split(","), multicast_scouting=False, shared_memory=False,
                        lease_s=2.0)
    q = QoSProfile(reliability="best_effort", depth=1, liveliness_lease_duration=float(sys.argv[3]))
    with Node("doomed", namespace=sys.argv[2], config=cfg) as node:
        pub = node.create_publisher(String, "beat", q)
        print("ready", flush=True)
        while True:
            pub.publish(String("x"))
            time.sleep(0.05)
""")


@pytest.mark.parametrize("lease", [1.0])
def test_sigkill_of_a_publisher_process_changes_liveliness_and_the_graph(ns, lease):
    listen, connect = linked_configs()
    # The graph forgets a dead process when Zenoh's transport does: at once when its TCP link
    # resets, after the transport lease when a UDP link is left (10 s by default; 2 s here).
    listen.lease_s = 2.0
    events = Events()
    with Node("watcher", namespace=ns, config=listen) as node:
        node.create_subscription(String, "beat", lambda m: None, BE.replace(liveliness_lease_duration=2 * lease),
                                 event_callbacks=events.sub_callbacks())
        child = python_proc("-c", PUBLISHER_CHILD, ",".join(connect.connect), ns, str(lease))
        try:
            assert node.spin_until(lambda: any(s.alive_count == 1 for s in events.get("liveliness")), 15.0), \
                events.by_kind
            assert node.count_publishers("beat") == 1
            info = node.get_publishers_info_by_topic("beat")[0]
            assert info.node_name == "doomed" and info.qos_profile.liveliness_lease_duration == lease
            child.send_signal(signal.SIGKILL)
            killed_at = time.monotonic()
            assert node.spin_until(lambda: events.get("liveliness")[-1].alive_count == 0, lease + 3.0)
            took = time.monotonic() - killed_at
            assert events.get("liveliness")[-1].alive_count_change == -1
            assert wait_for(lambda: node.count_publishers("beat") == 0, 2.0 + 3.0)
            print(f"graph updated {(time.monotonic() - killed_at) * 1000:.0f} ms after SIGKILL")
            print(f"liveliness change seen {took * 1000:.0f} ms after SIGKILL (lease {lease} s)")
        finally:
            child.kill()
            child.wait(5)


# -- compatibility ---------------------------------------------------------------------
INCOMPATIBLE = {
    PolicyKind.RELIABILITY: (BE, QoSProfile(depth=10)),
    PolicyKind.DURABILITY: (QoSProfile(depth=10), QoSProfile(durability="transient_local", depth=10)),
    PolicyKind.DEADLINE: (QoSProfile(deadline=0.5), QoSProfile(deadline=0.2)),
    PolicyKind.LIVELINESS: (QoSProfile(), QoSProfile(liveliness="manual_by_topic")),
    PolicyKind.LIVELINESS_LEASE_DURATION: (QoSProfile(liveliness_lease_duration=2.0),
                                           QoSProfile(liveliness_lease_duration=1.0)),
}


@pytest.mark.parametrize("policy", list(INCOMPATIBLE), ids=lambda p: p.name.lower())
def test_incompatible_pair_is_reported_on_both_sides_and_does_not_deliver(pair, policy):
    a, b = pair
    offered, requested = INCOMPATIBLE[policy]
    pub_events, sub_events = Events(), Events()
    got: list[str] = []
    sub = b.create_subscription(String, "strict", lambda m: got.append(m.data), requested,
                                event_callbacks=sub_events.sub_callbacks())
    pub = a.create_publisher(String, "strict", offered, event_callbacks=pub_events.pub_callbacks())
    assert wait_for(lambda: (spin_both(a, b, 0.02) or True) and sub_events.get("incompatible_qos")
                    and pub_events.get("incompatible_qos"), 5.0)
    requested_info, offered_info = sub_events.get("incompatible_qos")[0], pub_events.get("incompatible_qos")[0]
    assert requested_info.last_policy_kind is policy and offered_info.last_policy_kind is policy
    assert requested_info.total_count == 1 and offered_info.total_count_change == 1
    assert policy.name.split("_")[0].lower() in requested_info.reason.lower()
    for i in range(5):
        pub.publish(String(str(i)))
    spin_both(a, b, 0.5)
    assert got == [] and sub.counters.incompatible == 5
    assert sub.get_publisher_count() == 0 and pub.get_subscription_count() == 0
    assert sub_events.get("matched") == []


def test_compatible_pair_matches_delivers_and_raises_no_incompatibility(pair):
    a, b = pair
    pub_events, sub_events = Events(), Events()
    got: list[str] = []
    offered = QoSProfile(durability="transient_local", deadline=0.2, liveliness="manual_by_topic",
                         liveliness_lease_duration=1.0)
    sub = b.create_subscription(String, "ok", lambda m: got.append(m.data), BE.replace(deadline=1.0),
                                event_callbacks=sub_events.sub_callbacks())
    pub = a.create_publisher(String, "ok", offered, event_callbacks=pub_events.pub_callbacks())
    assert wait_for(lambda: sub.get_publisher_count() == 1 and pub.get_subscription_count() == 1, 5.0)
    pub.publish(String("hello"))
    assert b.spin_until(lambda: got == ["hello"], 3.0)
    spin_both(a, b, 0.1)
    assert sub_events.get("incompatible_qos") == [] and pub_events.get("incompatible_qos") == []
    assert sub_events.get("matched")[0].current_count == 1 and pub_events.get("matched")[0].current_count == 1
    a.destroy_publisher(pub)
    assert wait_for(lambda: (spin_both(a, b, 0.02) or True) and sub.get_publisher_count() == 0, 5.0)
    spin_both(a, b, 0.1)
    assert sub_events.get("matched")[-1].current_count_change == -1


def test_bad_event_callbacks_are_refused_clearly(pair):
    a, _ = pair
    with pytest.raises(TypeError, match="PublisherEventCallbacks"):
        a.create_publisher(String, "x", event_callbacks=SubscriptionEventCallbacks())
    with pytest.raises(TypeError, match="not callable"):
        a.create_subscription(String, "x", print, event_callbacks=SubscriptionEventCallbacks(deadline=42))


# -- message lost ----------------------------------------------------------------------
def test_sequence_gaps_raise_message_lost_with_the_count(pair, ns):
    a, b = pair
    events = Events()
    got: list[int] = []
    b.create_subscription(String, "gappy", lambda m, info: got.append(info.seq), BE.replace(depth=100),
                          event_callbacks=events.sub_callbacks())
    # A publisher whose packets 3, 4 and 7..9 never arrived: the bytes a real one sends.
    raw = a.session.declare_publisher(f"{ns}/gappy")
    time.sleep(0.3)
    for seq in (1, 2, 5, 6, 10, 11):
        ts = type_support(String)
        raw.put(envelope.pack(ts.name, ts.hash, 77, seq, time.time_ns(), ["x"]))
    assert b.spin_until(lambda: len(got) == 6, 3.0), got
    lost = events.get("message_lost")
    assert [e.total_count_change for e in lost] == [2, 3]
    assert lost[-1].total_count == 5


def test_queue_overflow_is_dropped_not_lost(pair):
    a, b = pair
    events = Events()
    sub = b.create_subscription(String, "burst", lambda m: None, BE.replace(depth=1),
                                event_callbacks=events.sub_callbacks())
    pub = a.create_publisher(String, "burst", BE.replace(depth=1))
    assert wait_for(lambda: sub.get_publisher_count() == 1, 5.0)
    for i in range(20):                        # not spinning: KEEP_LAST(1) keeps only the newest
        pub.publish(String(str(i)))
    assert wait_for(lambda: sub.counters.received == 20, 3.0)
    b.spin(timeout=0.2)
    assert sub.counters.dropped == 19 and sub.counters.lost == 0
    assert events.get("message_lost") == []


def test_garbage_heartbeats_are_ignored(pair, ns):
    a, b = pair
    events = Events()
    b.create_subscription(String, "hb2", lambda m: None, BE.replace(liveliness_lease_duration=1.0),
                          event_callbacks=events.sub_callbacks())
    pub = a.create_publisher(String, "hb2", BE.replace(liveliness_lease_duration=0.5))
    for junk in (b"\xff", msgpack.packb("nope"), msgpack.packb(12345)):
        a.session.put(f"@zr/alive/{ns}/hb2", junk)
    spin_both(a, b, 0.6)
    assert events.get("liveliness")[-1].alive_count == 1   # the automatic heartbeats keep it alive
    assert pub.get_subscription_count() == 1


def test_a_forged_token_with_a_publishers_gid_cannot_block_it(pair):
    """A publisher's gid is on the wire: a peer can declare a token naming it with an incompatible QoS.
    Before, claims were judged by gid: declaring, withdrawing and re-declaring such a token unmatched the
    real publisher and then blocked its samples (a blinded subscription). A compatible claim now wins."""
    from zenoh_robot.graph import PUBLISHER, endpoint_token_key

    a, b = pair
    got: list[str] = []
    reliable = QoSProfile(reliability="reliable", depth=10)
    sub = b.create_subscription(String, "victim", lambda m: got.append(m.data), reliable)
    pub = a.create_publisher(String, "victim", reliable)
    assert wait_for(lambda: sub.get_publisher_count() == 1, 5.0)
    real = next(iter(sub.events.matched.values()))
    forged = endpoint_token_key(PUBLISHER, "f" * 32, real.endpoint_gid, real.node_namespace, real.node_name,
                                real.key, real.topic_type, real.topic_type_hash, BE)   # best effort: incompatible
    for round_ in range(2):     # declare, withdraw, declare again
        token = a.session.liveliness().declare_token(forged)
        assert wait_for(lambda: len(b.get_publishers_info_by_topic(real.topic_name)) == 2, 5.0)
        spin_both(a, b, 0.1)
        if round_ == 0:
            token.undeclare()
            assert wait_for(lambda: len(b.get_publishers_info_by_topic(real.topic_name)) == 1, 5.0)
    assert sub.events.blocked == frozenset() and sub.get_publisher_count() == 1
    pub.publish(String("still heard"))
    assert b.spin_until(lambda: got == ["still heard"], 3.0)
    assert sub.counters.incompatible == 0
    token.undeclare()
