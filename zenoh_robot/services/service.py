"""A server: requests from queries and from put-carried copies, run once on the node's executor, answered.

Threads: the queryable and subscriber callbacks run on Zenoh's threads and only hand the request
to the node's executor; the handler runs and replies there, then the query is dropped so the
querier sees it finalised at once. A handler that must wait (e.g. for hardware) returns a
``concurrent.futures.Future`` instead of the response: the executor thread is free at once and the
reply goes out on the thread that completes the future. The package doc has the wire format and
the at-most-once contract.
"""
from __future__ import annotations

import hashlib
import logging
import math
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Generic, TypeVar

import msgpack
import zenoh

from .. import envelope
from ..context import EntityContext
from ..message import Message, require_message_type, type_support, validated
from ..ratelimit import RateLimitedLog
from ..wire.sealed import StaleSample, service_seal
from . import call_plan as plans
from .errors import _error_payload
from .idempotency import IdempotencyCache, Responder
from .keys import DESCRIBE_PARAM, REPLY_CHUNK, REQUEST_CHUNK, service_name_of_key
from .multicast import MAX_REPLY_PUBLISHERS, MULTICAST_REPLY_COPIES, _best_effort_publisher, _reply_attachment

Req = TypeVar("Req", bound=Message)
Resp = TypeVar("Resp", bound=Message)

log = logging.getLogger("zenoh_robot.services")    # one logger for the package, whichever module logs
MAX_REQUEST_BYTES = 16 << 20    # a request over this is refused (bad_request) before it is copied

# A handler answers at once (the response) or later (a Future of it: the reply goes when it completes).
Handler = Callable[[Req], "Resp | Future[Resp]"]
Outcome = tuple[bool, bytes, bool]   # (ok, reply payload, whether the handler ran)


class Service(Generic[Req, Resp]):
    """A server: ``handler(request) -> response`` run on the node's executor, at most once per request id.

    The handler may return a ``Future`` of the response instead: the reply (and joined duplicates'
    replies) go out when it completes, from the completing thread; an exception set on it is a
    ``handler`` error reply, like one raised by the handler.
    """

    def __init__(self, context: EntityContext, name: str, key: str, request_type: type[Req],
                 response_type: type[Resp], handler: Handler[Req, Resp]) -> None:
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
        self.stale_requests = 0   # sealed requests refused as not fresh (wire/freshness.py), answered `stale`
        self._stale_answers = (0.0, 0)    # (second, answers in it): a replay storm gets a bounded echo
        self._loss = math.nan     # set_loss: this node's loss estimate (sizes reply copies)
        self._recent_replies: OrderedDict[str, float] = OrderedDict()   # reply key -> when copies went out
        self._rlog = RateLimitedLog(log)
        # A sealing wire format (wire/sealed.py) seals calls too; None: plain envelopes, byte for byte as before.
        self._link = service_seal(context.wire, key, self._req, self._resp)
        self._queryable = context.session.declare_queryable(key, self._on_query, complete=True)
        # Every session: a multicast session carries calls only this way; on a unicast session
        # clients with AdaptiveRetry send best-effort copies here besides their query (package doc).
        self._request_sub: Any = context.session.declare_subscriber(f"{key}/{REQUEST_CHUNK}", self._on_put_request)
        self._reply_pubs: OrderedDict[int, Any] = OrderedDict()

    @property
    def cache_evictions(self) -> int:
        return self.cache.evictions

    def set_loss(self, loss: float) -> None:
        """This node's measured loss (0..1, e.g. ``loss_monitor.adapt(service.set_loss)``): sizes reply copies."""
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
                if self._link is not None:
                    data = self._link.seal_reply(data)
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
        payload: zenoh.ZBytes | bytes | None = query.payload
        if self._link is not None:
            answered: list[bool] = []

            def answer_stale(_inner: bytes, err: bytes) -> None:
                answered.append(True)
                respond(False, err)     # finalises the query
            payload = self._opened(query.payload, answer_stale)
            if payload is None:
                if not answered:
                    query.drop()
                return
        self._on_request(payload, respond)

    def _on_put_request(self, sample: zenoh.Sample) -> None:
        """Multicast sessions: a request put on ``<key>/@rq``; the reply goes to the client's own key."""
        if self._destroyed:
            return
        data: zenoh.ZBytes | bytes | None = sample.payload
        if self._link is not None:
            data = self._opened(sample.payload, self._answer_stale_put)
            if data is None:
                return
        assert data is not None
        try:
            raw = data if isinstance(data, bytes) else data.to_bytes() if len(data) <= MAX_REQUEST_BYTES else b""
            peek = envelope.unpack(raw) if raw and len(raw) <= MAX_REQUEST_BYTES else None
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

    def _put_reply(self, client_id: int, seq: int, ok: bool, payload: bytes, copies: int,
                   remember: bool = True) -> None:
        """The first copy now, the others REPLY_SPACING_S apart (each in its own datagram)."""
        now = time.monotonic()
        reply_key = f"{client_id}/{seq}"
        with self._lock:
            last = self._recent_replies.get(reply_key)
            # Joined duplicates are all answered at once when the handler ends: one burst of copies
            # serves them all. A request copy arriving later still gets its own copies.
            if remember and last is not None and now - last < plans.REPLY_SPACING_S:
                return
            if remember:
                self._recent_replies[reply_key] = now
                self._recent_replies.move_to_end(reply_key)
            while len(self._recent_replies) > self._RECENT_REPLIES:
                self._recent_replies.popitem(last=False)
            self.reply_copies += copies
            self.reply_bytes += copies * len(payload)
        attachment = _reply_attachment(seq, ok)
        try:
            pub = self._reply_publisher(client_id)

            link = self._link

            def put(data: bytes) -> None:     # on the repeater too: each copy sealed on its own
                pub.put(data if link is None else link.seal_reply(data), attachment=attachment)
            put(payload)
        except Exception as exc:
            log.debug("service %s: reply put failed: %s", self.service_name, exc)
            return
        if copies > 1:
            self.context.repeater.schedule(put, payload, copies - 1, plans.REPLY_SPACING_S)

    _STALE_ANSWERS_PER_S = 20

    def _answer_stale_put(self, inner: bytes, err: bytes) -> None:
        try:
            peek = envelope.unpack(inner)
        except envelope.MalformedSample:
            return
        # Not remembered as this call's reply burst: the call's real reply follows at once, when the
        # caller resends with the server's clock, and must not be taken for a duplicate burst.
        self._put_reply(peek.publisher_id, peek.seq, False, err, 1, remember=False)

    def _opened(self, payload: zenoh.ZBytes | None, answer_stale: Callable[[bytes, bytes], None]) -> bytes | None:
        """A sealed request's envelope, or None: refused (counted as a bad request and on the format).
        An authentic request that is not fresh (sealed for another start of this drone, or too old) is
        answered ``stale`` through ``answer_stale``, sealed with this node's clock, at a bounded rate:
        a legitimate caller learns the clock from it and sends again (client.py); a replay learns nothing."""
        assert self._link is not None
        try:
            if payload is None or len(payload) > MAX_REQUEST_BYTES + 64:
                opened = None
            else:
                opened = self._link.open_request(payload.to_bytes())
        except StaleSample as exc:
            now = int(time.monotonic())
            with self._lock:
                self.stale_requests += 1
                second, answers = self._stale_answers
                answers = answers + 1 if second == now else 1
                self._stale_answers = (now, answers)
            self._rlog.warning("stale", "service %s: refused a sealed request (%s)", self.service_name, exc.reason)
            if answers <= self._STALE_ANSWERS_PER_S:
                answer_stale(exc.inner, _error_payload(
                    "stale", f"service {self.service_name}: request refused ({exc.reason}: not sealed for this "
                    "start of the server, or too old); sent again with the server's clock"))
            return None
        if opened is None:
            with self._lock:
                self.bad_requests += 1
            self._rlog.warning("unsealed", "service %s: dropped a request without a valid seal", self.service_name)
        return opened

    def _on_request(self, payload: zenoh.ZBytes | bytes | None, respond: Responder) -> None:
        size = len(payload) if payload is not None else 0
        if size > MAX_REQUEST_BYTES:     # refused before it is copied
            respond(False, self._bad_request(f"request of {size} bytes is over the limit of {MAX_REQUEST_BYTES}"))
            return
        data = payload if isinstance(payload, bytes) else payload.to_bytes() if payload is not None else b""
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
            outcome = self._execute(data)
        except Exception as exc:   # never kill the executor, never leave joined duplicates hanging
            outcome = False, _error_payload("handler", f"internal error: {exc}"), False
        if isinstance(outcome, Future):   # answered later, by whoever completes the future
            outcome.add_done_callback(lambda done: self._finish(key, respond, self._settled(done)))
            return
        self._finish(key, respond, outcome)

    def _finish(self, key: bytes, respond: Responder, outcome: Outcome) -> None:
        ok, reply, executed = outcome
        for waiter in [respond, *self.cache.finish(key, (ok, reply), keep=executed)]:
            waiter(ok, reply)

    def _settled(self, done: Future[Outcome]) -> Outcome:
        try:
            return done.result()
        except BaseException as exc:  # noqa: BLE001  (cancelled or failed: the caller still gets an answer)
            with self._lock:
                self.errors += 1
            return False, _error_payload("handler", f"{type(exc).__name__}: {exc}"), True

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

    def _execute(self, data: bytes) -> Outcome | Future[Outcome]:
        """(ok, reply payload, whether the handler ran) for one request's bytes, or a Future of it."""
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
        except Exception as exc:
            return self._handler_error(exc)
        if not isinstance(response, Future):
            return self._encoded(response, env.seq, dict_form)
        later: Future[Outcome] = Future()

        def encode(done: Future[Resp]) -> None:   # the thread that completed the handler's future
            try:
                later.set_result(self._encoded(done.result(), env.seq, dict_form))
            except BaseException as exc:  # noqa: BLE001  (cancelled too: the caller hears it)
                later.set_result(self._handler_error(exc))
        response.add_done_callback(encode)
        return later

    def _encoded(self, response: object, seq: int, dict_form: bool) -> Outcome:
        resp_t = self._resp
        try:
            if not isinstance(response, self.response_type):
                raise TypeError(f"handler returned {type(response).__name__}, "
                                f"not {resp_t.name}")
            body = response.to_dict() if dict_form else resp_t.encode(response)
        except Exception as exc:
            return self._handler_error(exc)
        with self._lock:
            self.served += 1
        return True, envelope.pack(resp_t.name, resp_t.hash, self.server_id, seq, time.time_ns(), body,
                                   {"form": "dict"} if dict_form else None), True

    def _handler_error(self, exc: BaseException) -> Outcome:
        with self._lock:
            self.errors += 1
        self._rlog.warning("handler", "service %s: handler raised %s: %s", self.service_name,
                           type(exc).__name__, exc)
        return False, _error_payload("handler", f"{type(exc).__name__}: {exc}"), True

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
