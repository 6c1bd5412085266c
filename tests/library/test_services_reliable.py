"""At-least-once delivery, at-most-once execution of service calls (zenoh_robot.services), on real Zenoh sessions.

A handler counts its executions; requests are duplicated on the wire (the same bytes sent
again, as a retry does), replies are lost at the client, and the server's cache stays bounded.
"""
from __future__ import annotations

import threading
import time
from collections import Counter

import pytest
import zenoh
from conftest import linked_nodes, wait_for

from zenoh_robot import Message, RetryPolicy, envelope, message
from zenoh_robot import services as services_mod
from zenoh_robot.message import type_support
from zenoh_robot.services import IdempotencyCache, ServiceError, ServiceTimeout, ServiceUnavailable
from zenoh_robot.services import client as services_client

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


@message(name="test_services_reliable/Bump")
class Bump(Message):
    tag: str = ""
    delay_s: float = 0.0


@message(name="test_services_reliable/Count")
class Count(Message):
    executions: int = 0


class Counting:
    """A handler that counts how often it ran per tag (must be once per call)."""

    def __init__(self) -> None:
        self.runs: Counter[str] = Counter()
        self.lock = threading.Lock()

    def __call__(self, req: Bump) -> Count:
        time.sleep(req.delay_s)
        with self.lock:
            self.runs[req.tag] += 1
            return Count(self.runs[req.tag])


def _spin(node):
    t = threading.Thread(target=node.spin, daemon=True)
    t.start()
    return t


def _request_bytes(client_id: int, seq: int, req: Bump) -> bytes:
    ts, rs = type_support(Bump), type_support(Count)
    return envelope.pack(ts.name, ts.hash, client_id, seq, time.time_ns(), ts.encode(req),
                         {"rt": rs.name, "rh": rs.hash})


def _get(session: zenoh.Session, key: str, payload: bytes) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(key, payload=payload, timeout=3.0) if r.ok is not None]


def test_duplicated_requests_execute_once_and_get_the_same_reply(ns):
    handler = Counting()
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, handler)
        _spin(srv)
        client = cli.create_client("bump", Bump, Count)
        assert client.wait_for_service(5.0)
        payload = _request_bytes(client.client_id, 7, Bump("a"))
        replies = [_get(cli.session, client.key, payload) for _ in range(5)]   # the same request, 5 times
        assert all(len(r) == 1 for r in replies), replies
        assert len({r[0] for r in replies}) == 1, "a duplicate got a different reply"
        assert handler.runs["a"] == 1
        assert service.executions == 1 and service.duplicates == 4
        # Another request id is another call: it runs.
        _get(cli.session, client.key, _request_bytes(client.client_id, 8, Bump("a")))
        assert handler.runs["a"] == 2


def test_duplicate_of_a_running_request_joins_it(ns):
    handler = Counting()
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, handler)
        _spin(srv)
        client = cli.create_client("bump", Bump, Count)
        assert client.wait_for_service(5.0)
        payload = _request_bytes(client.client_id, 1, Bump("slow", delay_s=0.5))
        results: list[list[bytes]] = []
        threads = [threading.Thread(target=lambda: results.append(_get(cli.session, client.key, payload)))
                   for _ in range(4)]
        for t in threads:
            t.start()
            time.sleep(0.02)
        for t in threads:
            t.join(10)
        assert handler.runs["slow"] == 1, "a duplicate arriving while the first ran executed again"
        assert len(results) == 4 and all(len(r) == 1 for r in results), results
        assert type_support(Count).decode(envelope.unpack(results[0][0]).body).executions == 1
        assert service.duplicates == 3


def test_retried_call_with_lost_replies_executes_once_and_succeeds(ns, monkeypatch):
    """The server runs the command, its first two replies are lost: the client retries, gets the
    cached answer, the handler ran once."""
    handler = Counting()
    lost: list[int] = []
    real_on_reply = services_client._Call.on_reply

    def lossy_on_reply(self, reply):
        if reply.ok is not None and len(lost) < 2:
            lost.append(self.seq)      # the reply reached this host and was dropped: a lost reply
            return
        real_on_reply(self, reply)
    monkeypatch.setattr(services_client._Call, "on_reply", lossy_on_reply)
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, handler)
        _spin(srv)
        client = cli.create_client("bump", Bump, Count, retry=RetryPolicy(interval_s=0.1, multiplier=1.5))
        assert client.wait_for_service(5.0)
        res = client.call(Bump("cmd"), timeout=3.0)
        assert res.executions == 1
        assert len(lost) == 2 and handler.runs["cmd"] == 1 and service.executions == 1
        assert client.attempts >= 3 and service.duplicates >= 2


def test_without_retry_a_lost_reply_is_a_timeout(ns, monkeypatch):
    """The control: the same loss without retries fails, so the previous test measures the retries."""
    monkeypatch.setattr(services_client._Call, "on_reply", lambda self, reply: None)
    with linked_nodes(ns) as (cli, srv):
        srv.create_service("bump", Bump, Count, Counting())
        _spin(srv)
        client = cli.create_client("bump", Bump, Count, retry=None)
        assert client.wait_for_service(5.0)
        with pytest.raises((ServiceTimeout, ServiceUnavailable)):   # the query finalised without an answer
            client.call(Bump("x"), timeout=0.5)
        assert client.attempts == 1


def test_handler_error_is_final_and_cached(ns):
    runs = Counter()

    def failing(req: Bump) -> Count:
        runs[req.tag] += 1
        raise RuntimeError("refused")
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, failing)
        _spin(srv)
        client = cli.create_client("bump", Bump, Count, retry=RetryPolicy(interval_s=0.05))
        assert client.wait_for_service(5.0)
        t0 = time.monotonic()
        with pytest.raises(ServiceError) as err:
            client.call(Bump("e"), timeout=3.0)
        assert err.value.kind == "handler" and time.monotonic() - t0 < 2.5   # not retried to the deadline
        assert runs["e"] == 1 and service.executions == 1


def test_server_cache_is_bounded(ns):
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, Counting())
        service.cache = IdempotencyCache(max_entries=8, max_bytes=1 << 20)
        _spin(srv)
        client = cli.create_client("bump", Bump, Count)
        assert client.wait_for_service(5.0)
        for i in range(40):
            client.call(Bump(f"k{i}"), timeout=3.0)
        assert len(service.cache) == 8 and service.cache.evictions == 32
        assert service.executions == 40


def test_cache_limits_bytes_ttl_and_waiters():
    cache = IdempotencyCache(max_entries=100, max_bytes=1000, ttl_s=0.2, max_waiters=2)
    for i in range(10):
        assert cache.begin(bytes([i]), lambda ok, d: None) == ("new", None)
        cache.finish(bytes([i]), (True, b"x" * 300))
    assert cache.nbytes <= 1000 and len(cache) == 3
    assert cache.begin(bytes([9]), lambda ok, d: None) == ("done", (True, b"x" * 300))
    time.sleep(0.25)
    assert cache.begin(bytes([9]), lambda ok, d: None) == ("new", None)   # expired: forgotten
    assert len(cache) == 1
    for _ in range(5):
        assert cache.begin(bytes([9]), lambda ok, d: None) == ("joined", None)
    assert cache.dropped_waiters == 3 and len(cache.finish(bytes([9]), (True, b""))) == 2
    assert wait_for(lambda: True)


def test_call_plan_meets_the_target_and_bounds_the_cost():
    """The adaptive plan (zenoh_robot/services/call_plan.py): >= 99.9 % answered within 2 s at 50 % loss each way
    with no measurement, >= 99 % at a measured 90 %, and never more copies than its caps."""
    import math

    from zenoh_robot.services import call_plan as cp

    unknown = cp.call_plan(math.nan, 2.0)
    assert unknown.answered(0.5, 2.0) >= 0.999 and unknown.reply_copies > 1
    assert cp.call_plan(0.9, 2.0).answered(0.9, 2.0) >= 0.99
    assert unknown.answered(0.9, 2.0) >= 0.99                 # escalating gaps: 90 % without a measurement
    assert not cp.call_plan(0.0, 2.0).escalate               # measured clean: no escalation
    assert unknown.copies_within(2.0) <= 1 + 1.8 / cp.MIN_STEP_S
    # The old plan's reply copies shared a datagram: one reply per arriving request, 17 attempts.
    old = cp.CallPlan(step_s=2.0 / 17, reply_copies=1, loss=0.5)
    assert old.answered(0.5, 2.0) < 0.995
    for loss in (0.0, 0.2, 0.5, 0.9, 1.0, math.nan, math.inf):
        plan = cp.call_plan(loss, 2.0)
        assert cp.MIN_STEP_S <= plan.step_s <= cp.MAX_STEP_S
        assert 1 <= plan.reply_copies <= cp.MAX_REPLY_COPIES
    assert cp.call_plan(0.0, 2.0).reply_copies == 1          # a clean measured link: no extra copies
    for bad in (0, 17, -1, 2.5, "4", True, None):
        assert cp.requested_reply_copies(bad) is None       # a peer cannot ask for unbounded copies
    assert cp.requested_reply_copies(16) == 16


def test_put_carried_call_sends_the_asked_reply_copies_once_per_burst(ns, monkeypatch):
    """The multicast path (puts on @rq / @rp), here over a loopback unicast link: the request asks
    for 4 reply copies (client loss 50 %), the slow handler runs once while the retries join it,
    and the joined duplicates are answered by one burst of 4 spread copies, not 4 per duplicate."""
    from zenoh_robot.services import call_plan as cp

    monkeypatch.setattr(services_client, "is_multicast_session", lambda session: True)
    handler = Counting()
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, handler)
        _spin(srv)
        client = cli.create_client("bump", Bump, Count)
        assert client.retry is services_mod.ADAPTIVE_RETRY
        assert not client.discovers_servers   # no declarations on a multicast session: only answers tell
        client.set_loss(0.5)
        copies = cp.call_plan(0.5, 3.0).reply_copies
        assert copies == 4
        seen: list[float] = []
        sub = cli.session.declare_subscriber(f"{client.key}/{services_mod.REPLY_CHUNK}/**",
                                             lambda s: seen.append(time.monotonic()))
        time.sleep(0.5)       # the subscribers' declarations cross the link
        res = client.call(Bump("slow", delay_s=0.3), timeout=3.0)
        assert res.executions == 1 and handler.runs["slow"] == 1
        assert client.attempts >= 3 and service.duplicates >= 2       # retries went out and joined
        assert wait_for(lambda: len(seen) >= copies, 2.0)
        time.sleep(0.2)
        # One burst of `copies` for the request and every duplicate that joined it. A retry copy that a
        # loaded machine delivered after the reply went out gets a burst of its own (by design: it may be
        # the only copy that reached the server); a burst per joined duplicate would be `duplicates` more.
        bursts, rest = divmod(len(seen), copies)
        assert rest == 0 and len(seen) == service.reply_copies, (seen, service.reply_copies)
        assert 1 <= bursts <= service.duplicates, (bursts, service.duplicates)
        assert seen[-1] - seen[0] >= cp.REPLY_SPACING_S   # spread: not one datagram (4 copies span 15 ms)
        sub.undeclare()


def test_adaptive_call_to_a_server_that_answered_before_is_sent_without_discovery(ns):
    """A unicast session at 90 % loss re-forms its transport and loses the declarations for a while:
    an adaptive call to a server that has answered before still goes out (ServiceTimeout at the
    deadline if nothing comes back), while a plain call, or one to a never-seen server, fails fast."""
    with linked_nodes(ns) as (cli, srv):
        service = srv.create_service("bump", Bump, Count, Counting())
        _spin(srv)
        adaptive = cli.create_client("bump", Bump, Count, retry=services_mod.ADAPTIVE_RETRY)
        plain = cli.create_client("bump", Bump, Count, retry=None)
        never = cli.create_client("bump", Bump, Count, retry=services_mod.ADAPTIVE_RETRY)
        assert adaptive.wait_for_service(5.0)
        assert adaptive.call(Bump("a"), timeout=3.0).executions == 1
        srv.destroy_service(service)
        assert wait_for(lambda: not adaptive.service_is_ready(), 5.0)
        with pytest.raises(ServiceTimeout):
            adaptive.call(Bump("b"), timeout=0.5)
        assert adaptive.attempts > 2                     # it kept re-sending until the deadline
        with pytest.raises(ServiceUnavailable):
            plain.call(Bump("c"), timeout=0.5)
        with pytest.raises(ServiceUnavailable):
            never.call(Bump("d"), timeout=0.5)
