"""A client: a call's attempts (queries, put-carried copies), its retries and deadline, the reply decoded.

Threads: ``call`` blocks only its caller; replies arrive on Zenoh's threads and retries and
deadlines run on the shared scheduler thread (scheduler.py); each completes the call's Future
once. The package doc has the wire format and the at-least-once contract.
"""
from __future__ import annotations

import itertools
import math
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Generic, TypeVar

import zenoh

from .. import envelope
from ..context import EntityContext
from ..message import Message, TypeSupport, require_message_type, type_support
from ..session_config import is_multicast_session
from ..wire.sealed import service_seal
from . import call_plan as plans
from .errors import ServiceCallError, ServiceError, ServiceTimeout, ServiceUnavailable, decode_error
from .keys import REPLY_CHUNK, REQUEST_CHUNK, service_name_of_key
from .multicast import _best_effort_publisher, _parse_reply_attachment
from .retry import _DEFAULT, ADAPTIVE_RETRY, AdaptiveRetry, Retry, RetryPolicy
from .scheduler import _scheduler

Req = TypeVar("Req", bound=Message)
Resp = TypeVar("Resp", bound=Message)

# A fresh session needs a moment to learn the network's queryables; a call made
# this soon after the node started waits that long for a server before giving up.
DISCOVERY_GRACE_S = 1.0
# After the grace, a call without a known server still waits this long for one.
MATCH_WAIT_S = 0.2


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
        self._resent_stale = False  # sent again once after a `stale` answer (wire/freshness.py)
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
        if err is not None and err[0] == "stale":
            # A sealed server refused the request as sealed for another of its starts (or too old); its
            # sealed answer has just taught this node the server's clock, so the same request sent again
            # now is fresh. Once per call: the counted-out queries keep the call open meanwhile.
            query = not self.client._multicast
            with self._lock:
                self.errors.append(err)
                if self._resent_stale:
                    return
                self._resent_stale = True
                self._outstanding += 1 if query else 0
            _scheduler.at(time.monotonic(), lambda: self._resend(query))
            return
        if err is not None and err[0] != "busy":    # final: retrying would get the same answer
            self._finish(exc=ServiceError(err[1], err[0]))
            return
        with self._lock:
            self.errors.append(err)

    def _resend(self, query: bool) -> None:
        remaining = self.deadline - time.monotonic()
        if self.future.done() or self.client.context.closed or remaining <= 0.005:
            if query:
                self.on_done()
            return
        with self._lock:
            self.attempts += 1
        try:
            self.client._transmit(self, remaining, query)
        except Exception as exc:
            if query:
                with self._lock:
                    self._outstanding -= 1
            self._finish(exc=ServiceCallError(f"service {self.client.service_name}: cannot send: {exc}"))

    def on_reply(self, reply: zenoh.Reply) -> None:
        link = self.client._link
        if reply.ok is not None:
            data = reply.ok.payload.to_bytes()
            opened = data if link is None else self.client._opened_reply(data)
            if opened is not None:
                self.on_ok(opened)
        else:
            err = reply.err
            if err is None or link is None:
                self.on_err(decode_error(err.payload.to_bytes()) if err is not None else None)
                return
            opened = self.client._opened_reply(err.payload.to_bytes())
            if opened is not None:
                self.on_err(decode_error(opened))

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
        # Put-carried calls (see the package doc): always on multicast; on unicast for AdaptiveRetry.
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
        self.bad_replies = 0        # put-carried replies with an attachment that is not ours (or no valid seal)
        # A sealing wire format (wire/sealed.py) seals calls too; None: plain envelopes, byte for byte as before.
        self._link = service_seal(context.wire, key, self._req, self._resp)

    def set_loss(self, loss: float) -> None:
        """The link's measured loss (0..1), e.g. ``loss_monitor.adapt(client.set_loss)``."""
        self.loss = float(loss)

    # -- discovery -------------------------------------------------------------------
    @property
    def discovers_servers(self) -> bool:
        """Whether :meth:`service_is_ready` follows the servers' declarations (False on a multicast
        session, where none cross: it then says only whether a server has answered)."""
        return not self._multicast

    def service_is_ready(self) -> bool:
        if self._multicast:
            return self._answered
        try:
            status: Any = self._querier.matching_status   # a MatchingStatus (the stubs say bool)
            return bool(status.matching)
        except Exception:
            return False

    def wait_for_service(self, timeout: float | None = None, *, timeout_sec: float | None = None) -> bool:
        """Block until a server is known (True) or ``timeout`` seconds pass (False); None waits forever.
        ``timeout_sec`` is rclpy's name for it."""
        if timeout_sec is not None:
            timeout = timeout_sec
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
        link = self._link
        if call.puts:   # every copy sealed on its own (a new nonce): the server's window sees no replay
            self._request_pub.put(call.payload if link is None else link.seal_request(call.payload))
        if query:
            self.context.session.get(self.key, zenoh.handlers.Callback(call.on_reply, call.on_done),
                                     payload=call.payload if link is None else link.seal_request(call.payload),
                                     timeout=remaining,
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
        if self._link is not None:
            opened = self._opened_reply(data)
            if opened is None:
                return
            data = opened
        if ok:
            call.on_ok(data)
        else:
            call.on_err(decode_error(data))

    def _opened_reply(self, data: bytes) -> bytes | None:
        assert self._link is not None
        opened = self._link.open_reply(data)
        if opened is None:
            self.bad_replies += 1
        return opened

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
