"""Services over Zenoh queryables: typed request/response, with clear errors.

Key format: a service ``arm`` in namespace ``uav1`` is served on the Zenoh key
``@srv/uav1/arm`` (the name resolves like a topic, ``~/x`` and ``/x`` included,
then takes the ``@srv`` prefix). ``@srv`` is a Zenoh *verbatim* chunk: ``*`` and
``**`` never match it, so a topic subscriber on ``uav1/**`` or ``**`` never sees
service traffic and a service can share its name with a topic. ``@srv/**`` does
match every service (``zenoh-robot service list`` uses it).

Wire: the request is an envelope (envelope.py) of the request type whose
``extra`` names the response type the client expects (``rt``/``rh``); the reply
is an envelope of the response type. Failures are ``reply_err`` with the msgpack
array ``["zr-err", kind, text]`` (kind: ``handler``, ``type``, ``bad_request``,
``busy``), so the client tells them apart from Zenoh's own ``Timeout`` error.
A query with the selector parameter ``zr_describe`` gets the service's name and
types instead of a call. A request whose ``extra`` holds ``form: dict`` carries
the body as a mapping and gets the response as a mapping (the CLI uses it to call
services whose Python types it does not have).

Threads: the queryable callback runs on Zenoh's thread and only hands the query
to the node's executor; the handler runs and replies there, then the query is
dropped so the querier sees it finalised at once.

At-least-once delivery, at-most-once execution (lossy links):
- Request id: every request envelope carries the client's random ``client_id`` (as
  ``publisher_id``) and a per-client counter (``seq``); a retry re-sends the very same bytes.
- Retries: ``Client.call(req, timeout, retry=RetryPolicy(...))`` re-sends the request with
  backoff (first after ``interval_s``, each gap ``multiplier`` times the last, at most
  ``max_interval_s``) until a reply arrives or ``timeout`` passes; a reply to any attempt
  completes the call. :data:`ADAPTIVE_RETRY` instead sizes each call from the client's loss
  estimate (``client.set_loss``, e.g. fed by a LinkMonitor; 50 % when none) and the deadline
  (_wire/call_plan.py): a request copy every 10-50 ms, and on a multicast session the number of
  reply copies it asks for. A client's default (``create_client(..., retry=...)``) is no retry on
  a unicast session and ADAPTIVE_RETRY on a multicast session, where everything is best effort;
  :func:`command_retry` is ADAPTIVE_RETRY on both (a unicast link may be UDP). A ``busy``
  refusal is retried; handler, type and bad-request errors are final.
- Idempotency: the server keeps a bounded (entries, bytes) LRU, time-limited cache of recent
  requests (keyed by a digest of the request bytes: same client, same counter, same body) ->
  reply. A duplicate of a finished request gets the cached reply and never runs the handler
  again; a duplicate of a request still running waits for (joins) the first and gets its reply.
  Handler errors are cached too (the handler ran); busy, type and bad-request refusals are not.
  ``Service.executions`` / ``duplicates`` / ``cache_evictions`` count what happened.
- Multicast sessions (``SessionConfig.resilient``): Zenoh 1.10 routes no queries, and propagates no
  liveliness tokens or declarations, over its UDP multicast transport (measured: a ``get`` gets no
  reply, docs/lossy-link.md), but plain puts cross it. There a service also listens on the key
  ``<service key>/@rq`` and a client puts its request there; the server puts the reply on
  ``<service key>/@rp/<client_id>`` (attachment: the call's seq, 8 bytes big-endian, and a byte
  0 = response, 1 = error payload), which only that client subscribes to; both through
  best-effort publishers (the server keeps one per recent client, at most 64). Each request
  copy that arrives is answered with ``rc`` copies (the request's own field, 1..16, or what the
  server's ``set_loss`` estimate needs, the larger) spread 5 ms apart: Zenoh batches puts written
  within ~1 ms into one datagram, so copies sent back to back were lost together. ``@rq``/``@rp``
  are verbatim chunks, so ``@srv/**`` (service listing) never matches them.
  On a unicast session a client with AdaptiveRetry does both: its first attempt is a query
  (the reliable link, e.g. TCP, and what an ACL allowing only queries lets through) and every
  attempt also a best-effort put copy, which rides the session's UDP link when it has one: at
  50 % loss a TCP query alone waits on backed-off retransmissions (75 % answered within 2 s,
  docs/results/commands.md). The server's cache makes the two paths one call.
  On a multicast session, without discovery, a call that gets no answer ends in ServiceTimeout
  (never ServiceUnavailable), and ``service_is_ready()`` is True once a server has answered.
"""
from __future__ import annotations

import hashlib
import heapq
import itertools
import logging
import math
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import msgpack
import zenoh

from . import names
from ._ratelimit import RateLimitedLog
from ._wire import call_plan as plans
from ._wire import envelope
from .context import EntityContext
from .message import Message, TypeSupport, require_message_type, type_support, validated
from .session_config import is_multicast_session

if TYPE_CHECKING:
    from .node import Node

Req = TypeVar("Req", bound=Message)
Resp = TypeVar("Resp", bound=Message)

SERVICE_PREFIX = "@srv"
DESCRIBE_PARAM = "zr_describe"
_ERR_MAGIC = "zr-err"
# A fresh session needs a moment to learn the network's queryables; a call made
# this soon after the node started waits that long for a server before giving up.
DISCOVERY_GRACE_S = 1.0
# After the grace, a call without a known server still waits this long for one.
MATCH_WAIT_S = 0.2

log = logging.getLogger("zenoh_robot.services")
MAX_REQUEST_BYTES = 16 << 20    # a request over this is refused (bad_request) before it is copied


class ServiceCallError(Exception):
    """Base of every failed service call."""


class ServiceTimeout(ServiceCallError):
    """No reply within the timeout (the server may be slow, busy or not spinning)."""


class ServiceUnavailable(ServiceCallError):
    """No server for the service."""


class ServiceError(ServiceCallError):
    """The server replied with an error; ``kind`` says which (handler, type, bad_request, busy)."""

    def __init__(self, message: str, kind: str = "handler") -> None:
        super().__init__(message)
        self.kind = kind


def service_key(name: str, namespace: str = "", node_name: str = "") -> str:
    """The Zenoh key of a service name as seen from a node (see the module doc)."""
    return f"{SERVICE_PREFIX}/{names.resolve_topic(name, namespace, node_name)}"


def service_name_of_key(key: str) -> str:
    """``@srv/uav1/arm`` -> ``/uav1/arm``."""
    prefix = SERVICE_PREFIX + "/"
    return "/" + (key[len(prefix):] if key.startswith(prefix) else key)


def _error_payload(kind: str, text: str) -> bytes:
    return msgpack.packb([_ERR_MAGIC, kind, text], use_bin_type=True)


def decode_error(payload: bytes) -> tuple[str, str] | None:
    """(kind, text) of one of our error replies, or None for another error (Zenoh's Timeout)."""
    try:
        obj = msgpack.unpackb(payload, raw=False)
    except Exception:
        return None
    if isinstance(obj, list) and len(obj) == 3 and obj[0] == _ERR_MAGIC:
        return str(obj[1]), str(obj[2])
    return None


REQUEST_CHUNK = "@rq"    # multicast sessions: requests are put on <service key>/@rq
REPLY_CHUNK = "@rp"      # ... and replies on <service key>/@rp/<client_id>, attachment: seq (8 bytes) + flag
_REPLY_OK, _REPLY_ERR = 0, 1
MAX_REPLY_PUBLISHERS = 64    # server: best-effort reply publishers kept, one per recent client (LRU)


def _reply_attachment(seq: int, ok: bool) -> bytes:
    return (seq & 0xFFFFFFFFFFFFFFFF).to_bytes(8, "big") + bytes([_REPLY_OK if ok else _REPLY_ERR])


def _parse_reply_attachment(data: bytes | None) -> tuple[int, bool] | None:
    """(seq, ok) of a put-carried reply, or None if the attachment is not ours."""
    if data is None or len(data) != 9 or data[8] not in (_REPLY_OK, _REPLY_ERR):
        return None
    return int.from_bytes(data[:8], "big"), data[8] == _REPLY_OK


def _best_effort_publisher(session: zenoh.Session, key: str) -> Any:
    # Best effort: on a unicast session with a UDP and a TCP link this rides UDP (a lost copy is
    # replaced by the next, never queued behind a TCP retransmission); DROP: never block a caller.
    return session.declare_publisher(key, reliability=zenoh.Reliability.BEST_EFFORT,
                                     congestion_control=zenoh.CongestionControl.DROP,
                                     priority=zenoh.Priority.INTERACTIVE_HIGH)
# A reply on a multicast session goes out in spread copies (_wire/call_plan.py: as many as the
# client asks for, or the server's own loss estimate needs); this many when neither says.
MULTICAST_REPLY_COPIES = 2


@dataclass(frozen=True)
class RetryPolicy:
    """When a call re-sends its request (same request id) while no reply came, until its timeout.

    Gaps: ``interval_s``, then each ``multiplier`` times the previous, never over ``max_interval_s``.
    """
    interval_s: float = 0.1
    multiplier: float = 1.5
    max_interval_s: float = 1.0

    def __post_init__(self) -> None:
        if not (self.interval_s > 0 and self.multiplier >= 1.0 and self.max_interval_s >= self.interval_s):
            raise ValueError(f"RetryPolicy needs interval_s > 0, multiplier >= 1, max_interval_s >= interval_s: {self}")

    def delays(self) -> Iterator[float]:
        gap = self.interval_s
        while True:
            yield gap
            gap = min(self.max_interval_s, gap * self.multiplier)


# The multicast default. At 50 % loss each way one attempt is answered with p = 0.25, so what
# matters is attempts within the caller's deadline: 50 ms growing 10 % per try, capped at 200 ms,
# is ~17 attempts in 2 s (0.75^17 < 1 % unanswered). A command is ~100 bytes: the cost is nothing.
RESILIENT_RETRY = RetryPolicy(interval_s=0.05, multiplier=1.1, max_interval_s=0.2)
_DEFAULT: Any = object()     # "the client's own retry policy" (None means no retry)
# Unicast: queries ride a reliable link, so a retry only covers a link that broke and came back.
UNICAST_COMMAND_RETRY = RetryPolicy(interval_s=0.5, multiplier=2.0, max_interval_s=2.0)


@dataclass(frozen=True)
class AdaptiveRetry:
    """Retries sized per call from the client's loss estimate and the call's deadline (_wire/call_plan.py).

    Request copies go out every ``plan.step_s`` (10-50 ms) until a reply or the deadline; on a
    multicast session the request asks the server for ``plan.reply_copies`` spread reply copies.
    The estimate comes from ``client.set_loss`` (e.g. ``link_monitor.adapt(client.set_loss)``);
    without one the plan is sized for 50 % loss each way.
    """

    def plan(self, loss: float, timeout: float) -> plans.CallPlan:
        return plans.call_plan(loss, timeout)


ADAPTIVE_RETRY = AdaptiveRetry()
Retry = RetryPolicy | AdaptiveRetry


def command_retry(node: "Node") -> Retry:
    """The retry policy for commands (must arrive, must run once) on any session: adaptive.

    A unicast session's link may be UDP (best effort: a lost query is gone) as well as TCP, so
    commands get the same at-least-once retries there; the server's cache keeps them run once.
    """
    return ADAPTIVE_RETRY


class _Scheduler:
    """One daemon thread running due callbacks (retries, deadlines) for every client in the process."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._cv = threading.Condition()
        self._ids = itertools.count()
        self._thread: threading.Thread | None = None

    def at(self, when: float, fn: Callable[[], None]) -> None:
        with self._cv:
            heapq.heappush(self._heap, (when, next(self._ids), fn))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="zr-service-retries", daemon=True)
                self._thread.start()
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._heap or self._heap[0][0] > time.monotonic():
                    self._cv.wait(None if not self._heap else max(0.0, self._heap[0][0] - time.monotonic()))
                _, _, fn = heapq.heappop(self._heap)
            try:
                fn()
            except Exception as exc:     # a retry must never kill the thread every client shares
                log.debug("service retry callback failed: %s", exc)


_scheduler = _Scheduler()

Reply = tuple[bool, bytes]            # (ok, payload): a response envelope or an error payload
Responder = Callable[[bool, bytes], None]


@dataclass
class _CacheEntry:
    at: float
    reply: Reply | None = None                  # None while the first copy is still running
    waiters: list[Responder] = field(default_factory=list)


class IdempotencyCache:
    """Recent request digests -> reply: a duplicate is answered, never executed (see the module doc).

    Bounded three ways: ``max_entries`` (LRU), ``max_bytes`` of cached replies, ``ttl_s``; a running
    request holds at most ``max_waiters`` joined duplicates (more are dropped: their copies are
    retries of the same call, the earlier ones will get the answer).
    """

    def __init__(self, max_entries: int = 1024, max_bytes: int = 8 << 20, ttl_s: float = 120.0,
                 max_waiters: int = 32) -> None:
        self.max_entries, self.max_bytes, self.ttl_s, self.max_waiters = max_entries, max_bytes, ttl_s, max_waiters
        self._entries: OrderedDict[bytes, _CacheEntry] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.evictions = 0
        self.dropped_waiters = 0

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def nbytes(self) -> int:
        return self._bytes

    def begin(self, key: bytes, respond: Responder) -> tuple[str, Reply | None]:
        """("new", None): run it and call finish(); ("done", reply): answer with it; ("joined", None)."""
        now = time.monotonic()
        with self._lock:
            self._expire(now)
            entry = self._entries.get(key)
            if entry is None:
                self._entries[key] = _CacheEntry(now)
                self._trim()
                return "new", None
            self._entries.move_to_end(key)
            if entry.reply is not None:
                return "done", entry.reply
            if len(entry.waiters) < self.max_waiters:
                entry.waiters.append(respond)
            else:
                self.dropped_waiters += 1
            return "joined", None

    def finish(self, key: bytes, reply: Reply, keep: bool = True) -> list[Responder]:
        """Record the reply (or forget the request when ``keep`` is False); the joined waiters to answer."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                return []
            waiters, entry.waiters = entry.waiters, []
            if keep:
                entry.reply, entry.at = reply, time.monotonic()
                self._bytes += len(reply[1])
                self._trim()
            else:
                del self._entries[key]
            return waiters

    def _expire(self, now: float) -> None:
        while self._entries:
            key, entry = next(iter(self._entries.items()))
            if now - entry.at < self.ttl_s or entry.reply is None and now - entry.at < 2 * self.ttl_s:
                break
            self._drop(key)

    def _trim(self) -> None:
        while len(self._entries) > self.max_entries or self._bytes > self.max_bytes:
            self._drop(next(iter(self._entries)))
            self.evictions += 1

    def _drop(self, key: bytes) -> None:
        entry = self._entries.pop(key)
        if entry.reply is not None:
            self._bytes -= len(entry.reply[1])


class Service(Generic[Req, Resp]):
    """A server: ``handler(request) -> response`` run on the node's executor, at most once per request id."""

    def __init__(self, context: EntityContext, name: str, key: str, request_type: type[Req],
                 response_type: type[Resp], handler: Callable[[Req], Resp]) -> None:
        for what, t in (("request", request_type), ("response", response_type)):
            require_message_type(t, f"create_service {name!r}: {what} type")
        if not callable(handler):
            raise TypeError(f"create_service {name!r}: handler must be callable")
        self.context = context
        self._req = type_support(request_type)
        self._resp = type_support(response_type)
        self.name = name
        self.key = key
        self.service_name = service_name_of_key(key)
        self.request_type = request_type
        self.response_type = response_type
        self.handler = handler
        self.server_id = secrets.randbits(63)
        self.served = 0
        self.errors = 0
        self.executions = 0       # handler runs (a duplicate request never adds one)
        self.duplicates = 0       # requests answered from, or joined to, an earlier copy
        self.cache = IdempotencyCache()
        self._lock = threading.Lock()
        self._destroyed = False
        self.bad_requests = 0     # refused before the handler: malformed, oversize, a field off its schema
        self.reply_copies = 0     # multicast path: reply puts sent (copies included) ...
        self.reply_bytes = 0      # ... and their payload bytes
        self._loss = math.nan     # set_loss: this node's loss estimate (sizes reply copies)
        self._recent_replies: OrderedDict[str, float] = OrderedDict()   # reply key -> when copies went out
        self._rlog = RateLimitedLog(log)
        self._queryable = context.session.declare_queryable(key, self._on_query, complete=True)
        # Every session: a multicast session carries calls only this way; on a unicast session
        # clients with AdaptiveRetry send best-effort copies here besides their query (services doc).
        self._request_sub: Any = context.session.declare_subscriber(f"{key}/{REQUEST_CHUNK}", self._on_put_request)
        self._reply_pubs: OrderedDict[int, Any] = OrderedDict()

    @property
    def cache_evictions(self) -> int:
        return self.cache.evictions

    def set_loss(self, loss: float) -> None:
        """This node's measured loss (0..1, e.g. ``link_monitor.adapt(service.set_loss)``): sizes reply copies."""
        self._loss = float(loss)

    # Zenoh's thread: only hand over.
    def _on_query(self, query: zenoh.Query) -> None:
        if self._destroyed:
            query.drop()
            return
        if DESCRIBE_PARAM in str(query.parameters):
            # No user code involved: answer at once, so listing works even if the node does not spin.
            self._describe(query)
            return

        def respond(ok: bool, data: bytes) -> None:
            try:
                if ok:
                    query.reply(self.key, data)
                else:
                    query.reply_err(data)
            except Exception as exc:  # a reply can fail once the querier gave up
                log.debug("service %s: reply failed: %s", self.service_name, exc)
            finally:
                try:
                    query.drop()     # the querier sees this attempt finalised at once
                except Exception:
                    pass
        payload = query.payload
        self._on_request(payload, respond)

    def _on_put_request(self, sample: zenoh.Sample) -> None:
        """Multicast sessions: a request put on ``<key>/@rq``; the reply goes to the client's own key."""
        if self._destroyed:
            return
        data = sample.payload
        try:
            peek = envelope.unpack(data.to_bytes()) if len(data) <= MAX_REQUEST_BYTES else None
        except envelope.MalformedSample:
            peek = None
        if peek is None:    # no client to answer: count and drop
            with self._lock:
                self.bad_requests += 1
            self._rlog.warning("bad_request", "service %s: dropped a malformed or oversize multicast request",
                               self.service_name)
            return
        client_id, seq = peek.publisher_id, peek.seq
        asked = plans.requested_reply_copies(peek.extra.get(plans.REPLY_COPIES_KEY))
        own = plans.reply_copies_for(self._loss) if math.isfinite(self._loss) else MULTICAST_REPLY_COPIES
        copies = max(asked or 0, own)

        def respond(ok: bool, payload: bytes) -> None:
            self._put_reply(client_id, seq, ok, payload, copies)
        self._on_request(data, respond)

    _RECENT_REPLIES = 1024        # bounded: reply keys remembered for the burst check below

    def _reply_publisher(self, client_id: int) -> Any:
        with self._lock:
            pub = self._reply_pubs.get(client_id)
            if pub is not None:
                self._reply_pubs.move_to_end(client_id)
                return pub
        pub = _best_effort_publisher(self.context.session, f"{self.key}/{REPLY_CHUNK}/{client_id}")
        with self._lock:
            if self._destroyed:
                pub.undeclare()
                raise RuntimeError("service destroyed")
            self._reply_pubs[client_id] = pub
            old = [self._reply_pubs.popitem(last=False)[1] for _ in range(len(self._reply_pubs) - MAX_REPLY_PUBLISHERS)]
        for o in old:     # bounded: a flood of client ids must not grow us
            try:
                o.undeclare()
            except Exception:
                pass
        return pub

    def _put_reply(self, client_id: int, seq: int, ok: bool, payload: bytes, copies: int) -> None:
        """The first copy now, the others REPLY_SPACING_S apart (each in its own datagram)."""
        now = time.monotonic()
        reply_key = f"{client_id}/{seq}"
        with self._lock:
            last = self._recent_replies.get(reply_key)
            # Joined duplicates are all answered at once when the handler ends: one burst of copies
            # serves them all. A request copy arriving later still gets its own copies.
            if last is not None and now - last < plans.REPLY_SPACING_S:
                return
            self._recent_replies[reply_key] = now
            self._recent_replies.move_to_end(reply_key)
            while len(self._recent_replies) > self._RECENT_REPLIES:
                self._recent_replies.popitem(last=False)
            self.reply_copies += copies
            self.reply_bytes += copies * len(payload)
        attachment = _reply_attachment(seq, ok)
        try:
            pub = self._reply_publisher(client_id)

            def put(data: bytes) -> None:
                pub.put(data, attachment=attachment)
            put(payload)
        except Exception as exc:
            log.debug("service %s: reply put failed: %s", self.service_name, exc)
            return
        if copies > 1:
            self.context.repeater.schedule(put, payload, copies - 1, plans.REPLY_SPACING_S)

    def _on_request(self, payload: zenoh.ZBytes | None, respond: Responder) -> None:
        size = len(payload) if payload is not None else 0
        if size > MAX_REQUEST_BYTES:     # refused before it is copied
            respond(False, self._bad_request(f"request of {size} bytes is over the limit of {MAX_REQUEST_BYTES}"))
            return
        data = payload.to_bytes() if payload is not None else b""
        key = hashlib.blake2b(data, digest_size=16).digest()
        state, cached = self.cache.begin(key, respond)
        if state != "new":
            with self._lock:
                self.duplicates += 1
            if cached is not None:
                respond(*cached)
            return
        if not self.context.executor.call_soon(lambda: self._run(key, data, respond)):
            busy = _error_payload("busy", f"service {self.service_name}: server queue full, request dropped")
            for waiter in [respond, *self.cache.finish(key, (False, busy), keep=False)]:
                waiter(False, busy)

    def _run(self, key: bytes, data: bytes, respond: Responder) -> None:
        try:
            ok, reply, executed = self._execute(data)
        except Exception as exc:   # never kill the executor, never leave joined duplicates hanging
            ok, reply, executed = False, _error_payload("handler", f"internal error: {exc}"), False
        for waiter in [respond, *self.cache.finish(key, (ok, reply), keep=executed)]:
            waiter(ok, reply)

    def describe(self) -> dict[str, Any]:
        return {"service": service_name_of_key(self.key), "node": self.context.fully_qualified_name,
                "request": self._req.name, "request_hash": self._req.hash,
                "response": self._resp.name, "response_hash": self._resp.hash}

    def _describe(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.key, msgpack.packb(self.describe(), use_bin_type=True))
        except Exception as exc:
            log.debug("service %s: describe reply failed: %s", self.service_name, exc)
        finally:
            try:
                query.drop()
            except Exception:
                pass

    def _execute(self, data: bytes) -> tuple[bool, bytes, bool]:
        """(ok, reply payload, whether the handler ran) for one request's bytes."""
        try:
            env = envelope.unpack(data)
        except envelope.MalformedSample as exc:
            return False, self._bad_request(f"malformed request ({exc})"), False
        rt, resp_t = self._req, self._resp
        dict_form = env.extra.get("form") == "dict"
        if env.type_hash != rt.hash or env.type_name != rt.name:
            return False, _error_payload("type", f"service {self.service_name} takes {rt.name} ({rt.hash}), "
                                                 f"got {env.type_name} ({env.type_hash})"), False
        want_name, want_hash = env.extra.get("rt"), env.extra.get("rh")
        if want_hash is not None and (want_hash != resp_t.hash or want_name != resp_t.name):
            return False, _error_payload("type", f"service {self.service_name} returns {resp_t.name} "
                                                 f"({resp_t.hash}), client expects {want_name} ({want_hash})"), False
        try:
            # Both forms are checked field by field (types, ranges, lengths): a handler never sees
            # force='yes' or a NaN where an int belongs; the caller gets a ServiceError naming the field.
            if dict_form:
                request = validated(self.request_type.from_dict(env.body))
            else:
                request = rt.decode(env.body)
        except Exception as exc:
            return False, self._bad_request(f"cannot decode {rt.name}: {str(exc)[:500]}"), False
        with self._lock:
            self.executions += 1
        try:
            response = self.handler(request)
            if not isinstance(response, self.response_type):
                raise TypeError(f"handler returned {type(response).__name__}, "
                                f"not {resp_t.name}")
            body = response.to_dict() if dict_form else resp_t.encode(response)
        except Exception as exc:
            with self._lock:
                self.errors += 1
            self._rlog.warning("handler", "service %s: handler raised %s: %s", self.service_name,
                               type(exc).__name__, exc)
            return False, _error_payload("handler", f"{type(exc).__name__}: {exc}"), True
        with self._lock:
            self.served += 1
        return True, envelope.pack(resp_t.name, resp_t.hash, self.server_id, env.seq, time.time_ns(), body,
                                   {"form": "dict"} if dict_form else None), True

    def _bad_request(self, why: str) -> bytes:
        with self._lock:
            self.bad_requests += 1
        self._rlog.warning("bad_request", "service %s: refused a request: %s", self.service_name, why)
        return _error_payload("bad_request", f"service {self.service_name}: {why}")

    def destroy(self) -> None:
        self._destroyed = True
        with self._lock:
            reply_pubs, self._reply_pubs = list(self._reply_pubs.values()), OrderedDict()
        for handle in (self._queryable, self._request_sub, *reply_pubs):
            try:
                if handle is not None:
                    handle.undeclare()
            except Exception:
                pass  # already closed with the session


class _Call:
    """One call: its attempts (same bytes), the replies they collect, the future completed once."""

    def __init__(self, client: Client[Any, Any], future: Future[Any], timeout: float, dict_form: bool,
                 seq: int, payload: bytes, delays: Iterator[float] | None, puts: bool = False) -> None:
        self.client = client
        self.puts = puts            # best-effort put copies (multicast: the only way; unicast: besides the query)
        self.future = future
        self.timeout = timeout
        self.dict_form = dict_form
        self.seq = seq
        self.payload = payload
        self.started = time.monotonic()
        self.deadline = self.started + timeout
        self.errors: list[tuple[str, str] | None] = []
        self.attempts = 0
        self._delays = delays
        self._outstanding = 0       # queries in flight (unicast path)
        self._more = True           # another attempt may still be sent
        self._lock = threading.Lock()

    def start(self) -> None:
        if self.puts:
            _scheduler.at(self.deadline, self.on_deadline)
        self.attempt()

    def attempt(self) -> None:
        if self.future.done() or self.client.context.closed:
            return
        now = time.monotonic()
        remaining = self.deadline - now
        if remaining <= 0.005:
            with self._lock:
                self._more = False
            return
        gap = next(self._delays) if self._delays is not None else None
        with self._lock:
            self.attempts += 1
            self._more = gap is not None and now + gap < self.deadline
            # Unicast: a query per attempt; with put copies only the first (it rides the reliable
            # link, which retransmits by itself: a second query would only queue behind the first).
            query = not self.client._multicast and (not self.puts or self.attempts == 1)
            self._outstanding += 1 if query else 0
        if self._more and gap is not None:
            _scheduler.at(now + gap, self.attempt)
        try:
            self.client._transmit(self, remaining, query)
        except Exception as exc:    # a closed session: the call fails, it does not hang
            with self._lock:
                self._outstanding -= 1 if query else 0
            self._finish(exc=ServiceCallError(f"service {self.client.service_name}: cannot send: {exc}"))

    def on_ok(self, data: bytes) -> None:
        if self.future.done():
            return
        try:
            result = self.client._decode_response(data, self.dict_form)
        except ServiceCallError as exc:
            self._finish(exc=exc)
            return
        self.client._answered = True
        self._finish(result=result)

    def on_err(self, err: tuple[str, str] | None) -> None:
        if err is not None:
            self.client._answered = True
        if err is not None and err[0] != "busy":    # final: retrying would get the same answer
            self._finish(exc=ServiceError(err[1], err[0]))
            return
        with self._lock:
            self.errors.append(err)

    def on_reply(self, reply: zenoh.Reply) -> None:
        if reply.ok is not None:
            self.on_ok(reply.ok.payload.to_bytes())
        else:
            err = reply.err
            self.on_err(decode_error(err.payload.to_bytes()) if err is not None else None)

    def on_done(self) -> None:
        with self._lock:
            self._outstanding -= 1
            last = self._outstanding <= 0 and not self._more
        if last:
            self.conclude()

    def on_deadline(self) -> None:
        self.conclude(timed_out=True)

    def conclude(self, timed_out: bool = False) -> None:
        if self.future.done():
            return
        self.client._forget(self)
        name = self.client.service_name
        ours = [e for e in self.errors if e is not None]
        if ours:
            kind, text = ours[-1]
            self._finish(exc=ServiceError(text, kind))
        elif timed_out or self.errors or time.monotonic() - self.started >= self.timeout * 0.9:
            self._finish(exc=ServiceTimeout(f"service {name}: no reply within {self.timeout:g} s "
                                            f"({self.attempts} attempt{'s' if self.attempts != 1 else ''})"))
        else:
            self._finish(exc=ServiceUnavailable(f"service {name}: no server"))

    def _finish(self, result: Any = None, exc: BaseException | None = None) -> None:
        self.client._forget(self)
        try:
            if exc is not None:
                self.future.set_exception(exc)
            else:
                self.future.set_result(result)
        except Exception:
            pass  # cancelled or already completed by the other path


class Client(Generic[Req, Resp]):
    """``client.call(request, timeout, retry=...)`` -> response, or a ServiceCallError subclass."""

    MAX_PENDING = 1024      # multicast path: calls awaiting a reply (older ones are failed first)

    def __init__(self, context: EntityContext, name: str, key: str, request_type: type[Req],
                 response_type: type[Resp] | None, *, request_support: TypeSupport | None = None,
                 retry: Retry | None | Any = _DEFAULT) -> None:
        # request_support: a request type known only by name and hash (call_dict); else request_type's.
        if request_support is None:
            require_message_type(request_type, f"create_client {name!r}: request type")
        if response_type is not None:
            require_message_type(response_type, f"create_client {name!r}: response type")
        self.context = context
        self._req = request_support or type_support(request_type)
        self._resp = type_support(response_type) if response_type is not None else None
        self.name = name
        self.key = key
        self.service_name = service_name_of_key(key)
        self.request_type = request_type
        self.response_type = response_type
        self.client_id = secrets.randbits(63)
        self._seq = itertools.count(1)
        self._multicast = is_multicast_session(context.session)
        if retry is _DEFAULT:
            retry = ADAPTIVE_RETRY if self._multicast else None
        if retry is not None and not isinstance(retry, (RetryPolicy, AdaptiveRetry)):
            raise TypeError(f"create_client {name!r}: retry must be a RetryPolicy, AdaptiveRetry or None, "
                            f"got {retry!r}")
        self.retry: Retry | None = retry
        # Put-carried calls (see the module doc): always on multicast; on unicast for AdaptiveRetry.
        self._puts = self._multicast or isinstance(retry, AdaptiveRetry)
        self.loss = math.nan        # set_loss: the link's measured loss (sizes AdaptiveRetry's plan)
        self.attempts = 0           # requests sent, retries included
        self.request_bytes = 0      # their payload bytes
        self._answered = False      # a server replied once (readiness on multicast, where nothing is discovered)
        self._pending: OrderedDict[int, _Call] = OrderedDict()
        self._pending_lock = threading.Lock()
        self._querier = context.session.declare_querier(key)
        self._reply_sub: Any = None
        self._request_pub: Any = None
        if self._puts:
            self._reply_sub = context.session.declare_subscriber(
                f"{key}/{REPLY_CHUNK}/{self.client_id}", self._on_reply_sample)
            self._request_pub = _best_effort_publisher(context.session, f"{key}/{REQUEST_CHUNK}")
        self.bad_replies = 0        # put-carried replies with an attachment that is not ours

    def set_loss(self, loss: float) -> None:
        """The link's measured loss (0..1), e.g. ``link_monitor.adapt(client.set_loss)``."""
        self.loss = float(loss)

    # -- discovery -------------------------------------------------------------------
    def service_is_ready(self) -> bool:
        if self._multicast:
            return self._answered
        try:
            status: Any = self._querier.matching_status   # a MatchingStatus (the stubs say bool)
            return bool(status.matching)
        except Exception:
            return False

    def wait_for_service(self, timeout: float | None = None) -> bool:
        """Block until a server is known (True) or ``timeout`` seconds pass (False); None waits forever."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.service_is_ready():
            if self.context.closed:
                return False
            if deadline is not None and time.monotonic() >= deadline:
                return False
            time.sleep(0.02)
        return True

    # -- calls -----------------------------------------------------------------------
    def call(self, request: Req, timeout: float = 2.0, retry: Retry | None | Any = _DEFAULT) -> Resp:
        """Send ``request`` and wait for the response (retried per ``retry``, default the client's policy).

        Blocks only this thread: replies arrive on Zenoh's threads, so calling this from a
        callback of a single-threaded executor does not deadlock (unless the server is a
        service of the same executor, which then cannot run: ServiceTimeout).
        """
        if not self._multicast and not self.service_is_ready():
            started = self.context.started
            grace = max(MATCH_WAIT_S, DISCOVERY_GRACE_S - (time.monotonic() - started))
            if not self.wait_for_service(min(timeout, grace)) and not self._resend_blind(retry):
                raise ServiceUnavailable(f"service {self.service_name}: no server")
        future = self.call_async(request, timeout, retry=retry)
        try:
            return future.result(timeout + 2.0)  # Zenoh finalises at `timeout`; the margin is a backstop
        except FutureTimeout:
            raise ServiceTimeout(f"service {self.service_name}: no reply within {timeout:g} s") from None

    def _resend_blind(self, retry: Retry | None | Any) -> bool:
        """Whether a call goes out although discovery shows no server: a unicast session at 90 % loss
        drops and re-forms its transport, losing the declarations for a while, yet a server that has
        answered before is likely still there and best-effort put copies may reach it meanwhile."""
        policy = self.retry if retry is _DEFAULT else retry
        return self._answered and self._puts and isinstance(policy, AdaptiveRetry)

    def call_async(self, request: Req, timeout: float = 2.0,
                   retry: Retry | None | Any = _DEFAULT) -> "Future[Resp]":
        """Send ``request``; the Future completes on a Zenoh thread (keep done-callbacks short)."""
        if not isinstance(request, self.request_type):
            raise TypeError(f"service {self.service_name} client takes {self._req.name}, "
                            f"got {type(request).__name__}")
        return self._send(self._req.encode(request), timeout, dict_form=False, retry=retry)

    def _send(self, body: Any, timeout: float, dict_form: bool,
              retry: Retry | None | Any = _DEFAULT) -> Future[Any]:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 seconds, got {timeout!r}")
        if retry is _DEFAULT:
            retry = self.retry
        self.context.check_open()
        future: Future[Any] = Future()
        extra: dict[str, Any] = {}
        if self._resp is not None:
            extra = {"rt": self._resp.name, "rh": self._resp.hash}
        if dict_form:
            extra["form"] = "dict"
        delays: Iterator[float] | None = None
        puts = self._multicast or (self._puts and isinstance(retry, AdaptiveRetry))
        if isinstance(retry, AdaptiveRetry):
            plan = retry.plan(self.loss, timeout)
            delays = plan.delays()
            if puts:
                extra[plans.REPLY_COPIES_KEY] = plan.reply_copies
        elif isinstance(retry, RetryPolicy):
            delays = retry.delays()
        seq = next(self._seq)
        # Packed once: every retry carries the same bytes, so the server recognises the duplicate.
        payload = envelope.pack(self._req.name, self._req.hash, self.client_id, seq, time.time_ns(), body, extra)
        call = _Call(self, future, timeout, dict_form, seq, payload, delays, puts)
        if puts:
            with self._pending_lock:
                self._pending[seq] = call
                overflow = [self._pending.popitem(last=False)[1] for _ in range(len(self._pending) - self.MAX_PENDING)]
            for old in overflow:
                old._finish(exc=ServiceTimeout(f"service {self.service_name}: too many calls in flight"))
        call.start()
        return future

    def _transmit(self, call: _Call, remaining: float, query: bool) -> None:
        self.attempts += 1
        self.request_bytes += len(call.payload) * (int(call.puts) + int(query))
        if call.puts:
            self._request_pub.put(call.payload)
        if query:
            self.context.session.get(self.key, zenoh.handlers.Callback(call.on_reply, call.on_done),
                                     payload=call.payload, timeout=remaining,
                                     priority=zenoh.Priority.INTERACTIVE_HIGH)

    def _on_reply_sample(self, sample: zenoh.Sample) -> None:
        """Put-carried path: a reply on ``<key>/@rp/<client_id>``, its seq and kind in the attachment."""
        attachment = sample.attachment
        parsed = _parse_reply_attachment(attachment.to_bytes() if attachment is not None else None)
        if parsed is None:
            self.bad_replies += 1
            return
        seq, ok = parsed
        with self._pending_lock:
            call = self._pending.get(seq)
        if call is None:
            return        # a late duplicate of an answered call
        data = sample.payload.to_bytes()
        if ok:
            call.on_ok(data)
        else:
            call.on_err(decode_error(data))

    def _forget(self, call: _Call) -> None:
        if call.puts:
            with self._pending_lock:
                self._pending.pop(call.seq, None)

    def _decode_response(self, data: bytes, dict_form: bool) -> Any:
        try:
            env = envelope.unpack(data)
        except envelope.MalformedSample as exc:
            raise ServiceError(f"service {self.service_name}: malformed response ({exc})", "bad_response") from None
        rt = self._resp
        if rt is not None and (env.type_hash != rt.hash or env.type_name != rt.name):
            raise ServiceError(f"service {self.service_name} returned {env.type_name} ({env.type_hash}), "
                               f"expected {rt.name} ({rt.hash})", "type")
        if dict_form or rt is None:
            return env.body
        try:
            return rt.decode(env.body)
        except Exception as exc:
            raise ServiceError(f"service {self.service_name}: cannot decode {env.type_name}: {exc}",
                               "bad_response") from None

    def destroy(self) -> None:
        for handle in (self._querier, self._reply_sub, self._request_pub):
            try:
                if handle is not None:
                    handle.undeclare()
            except Exception:
                pass


def _dict_form(name: str, hash_: str) -> TypeSupport:
    """A request type known only by name and hash (from a describe reply): bodies are mappings."""
    return TypeSupport(name, hash_, dict, dict, Message)


def describe_services(session: zenoh.Session, pattern: str = f"{SERVICE_PREFIX}/**",
                      timeout: float = 1.0) -> list[dict[str, Any]]:
    """Ask every server matching ``pattern`` for its name and types (served by spinning nodes)."""
    found: list[dict[str, Any]] = []
    for reply in session.get(f"{pattern}?{DESCRIBE_PARAM}", target=zenoh.QueryTarget.ALL, timeout=timeout,
                             consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is None:
            continue
        try:
            info = msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
        except Exception:
            continue
        if isinstance(info, dict) and "service" in info:
            found.append(info)
    return sorted(found, key=lambda d: d["service"])


def call_dict(node: "Node", service: str, request: dict[str, Any], timeout: float = 2.0) -> dict[str, Any]:
    """Call a service by its absolute name with a mapping, without its Python types (for the CLI)."""
    key = service_key(service if service.startswith("/") else "/" + service)
    client: Client[Any, Any] = Client(node.entity_context, service, key, Message, None,
                                      request_support=_dict_form("", ""))
    try:
        if not client.wait_for_service(min(timeout, DISCOVERY_GRACE_S)):
            raise ServiceUnavailable(f"service {client.service_name}: no server")
        infos = describe_services(node.session, key, timeout=min(timeout, 2.0))
        if not infos:
            raise ServiceUnavailable(f"service {client.service_name}: no server")
        client._req = _dict_form(str(infos[0]["request"]), str(infos[0]["request_hash"]))
        future = client._send(request, timeout, dict_form=True)
        try:
            result: dict[str, Any] = future.result(timeout + 2.0)
            return result
        except FutureTimeout:
            raise ServiceTimeout(f"service {client.service_name}: no reply within {timeout:g} s") from None
    finally:
        client.destroy()


class Services:
    """A node's services and clients (the node owns one and delegates ``create_service`` etc. to it)."""

    def __init__(self, context: EntityContext) -> None:
        self._context = context
        self._lock = threading.Lock()
        self.services: list[Service[Any, Any]] = []
        self.clients: list[Client[Any, Any]] = []

    def resolve_service_name(self, name: str) -> str:
        """The Zenoh key of service ``name``: ``arm`` in ``uav1`` -> ``@srv/uav1/arm``."""
        return service_key(name, self._context.namespace, self._context.node_name)

    def create_service(self, name: str, request_type: type[Req], response_type: type[Resp],
                       handler: Callable[[Req], Resp]) -> Service[Req, Resp]:
        self._context.check_open()
        srv = Service(self._context, name, self.resolve_service_name(name), request_type, response_type, handler)
        with self._lock:
            self.services.append(srv)
        return srv

    def create_client(self, name: str, request_type: type[Req], response_type: type[Resp],
                      retry: Retry | None | Any = _DEFAULT) -> Client[Req, Resp]:
        """``retry``: RetryPolicy, AdaptiveRetry or None (one attempt); default: ADAPTIVE_RETRY on multicast."""
        self._context.check_open()
        if not (isinstance(response_type, type) and issubclass(response_type, Message)):
            raise TypeError(f"create_client {name!r}: response type {response_type!r} is not a message type")
        client = Client(self._context, name, self.resolve_service_name(name), request_type, response_type,
                        retry=retry)
        with self._lock:
            self.clients.append(client)
        return client

    def destroy_service(self, srv: Service[Any, Any]) -> None:
        with self._lock:
            if srv in self.services:
                self.services.remove(srv)
        srv.destroy()

    def destroy_client(self, client: Client[Any, Any]) -> None:
        with self._lock:
            if client in self.clients:
                self.clients.remove(client)
        client.destroy()

    def close(self) -> None:
        with self._lock:
            entities: list[Service[Any, Any] | Client[Any, Any]] = [*self.services, *self.clients]
        for entity in entities:
            entity.destroy()
