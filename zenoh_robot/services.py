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
"""
from __future__ import annotations

import itertools
import logging
import secrets
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import msgpack
import zenoh

from . import names
from ._ratelimit import RateLimitedLog
from ._wire import envelope
from .context import EntityContext
from .message import Message, TypeSupport, require_message_type, type_support, validated

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


class Service(Generic[Req, Resp]):
    """A server: ``handler(request) -> response`` run on the node's executor."""

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
        self._lock = threading.Lock()
        self._destroyed = False
        self.bad_requests = 0     # refused before the handler: malformed, oversize, a field off its schema
        self._rlog = RateLimitedLog(log)
        self._queryable = context.session.declare_queryable(key, self._on_query, complete=True)

    # Zenoh's thread: only hand over.
    def _on_query(self, query: zenoh.Query) -> None:
        if self._destroyed:
            query.drop()
            return
        if DESCRIBE_PARAM in str(query.parameters):
            # No user code involved: answer at once, so listing works even if the node does not spin.
            self._serve(query)
            return
        if not self.context.executor.call_soon(lambda: self._serve(query)):
            self._reply_err(query, "busy", f"service {self.service_name}: server queue full, request dropped")
            query.drop()

    def describe(self) -> dict[str, Any]:
        return {"service": service_name_of_key(self.key), "node": self.context.fully_qualified_name,
                "request": self._req.name, "request_hash": self._req.hash,
                "response": self._resp.name, "response_hash": self._resp.hash}

    def _serve(self, query: zenoh.Query) -> None:
        try:
            if DESCRIBE_PARAM in str(query.parameters):
                query.reply(self.key, msgpack.packb(self.describe(), use_bin_type=True))
                return
            self._call(query)
        except Exception as exc:  # a reply can fail once the querier gave up; never kill the executor
            log.debug("service %s: reply failed: %s", self.service_name, exc)
        finally:
            try:
                query.drop()
            except Exception:
                pass

    def _call(self, query: zenoh.Query) -> None:
        payload = query.payload
        size = len(payload) if payload is not None else 0
        if size > MAX_REQUEST_BYTES:     # refused before it is copied
            self._bad_request(query, f"request of {size} bytes is over the limit of {MAX_REQUEST_BYTES}")
            return
        try:
            env = envelope.unpack(payload.to_bytes() if payload is not None else b"")
        except envelope.MalformedSample as exc:
            self._bad_request(query, f"malformed request ({exc})")
            return
        rt, resp_t = self._req, self._resp
        dict_form = env.extra.get("form") == "dict"
        if env.type_hash != rt.hash or env.type_name != rt.name:
            self._reply_err(query, "type",
                            f"service {self.service_name} takes {rt.name} ({rt.hash}), "
                            f"got {env.type_name} ({env.type_hash})")
            return
        want_name, want_hash = env.extra.get("rt"), env.extra.get("rh")
        if want_hash is not None and (want_hash != resp_t.hash or want_name != resp_t.name):
            self._reply_err(query, "type",
                            f"service {self.service_name} returns {resp_t.name} "
                            f"({resp_t.hash}), client expects {want_name} ({want_hash})")
            return
        try:
            # Both forms are checked field by field (types, ranges, lengths): a handler never sees
            # force='yes' or a NaN where an int belongs; the caller gets a ServiceError naming the field.
            if dict_form:
                request = validated(self.request_type.from_dict(env.body))
            else:
                request = rt.decode(env.body)
        except Exception as exc:
            self._bad_request(query, f"cannot decode {rt.name}: {str(exc)[:500]}")
            return
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
            self._reply_err(query, "handler", f"{type(exc).__name__}: {exc}")
            return
        query.reply(self.key, envelope.pack(resp_t.name, resp_t.hash,
                                            self.server_id, env.seq, time.time_ns(), body,
                                            {"form": "dict"} if dict_form else None))
        with self._lock:
            self.served += 1

    def _bad_request(self, query: zenoh.Query, why: str) -> None:
        with self._lock:
            self.bad_requests += 1
        self._rlog.warning("bad_request", "service %s: refused a request: %s", self.service_name, why)
        self._reply_err(query, "bad_request", f"service {self.service_name}: {why}")

    @staticmethod
    def _reply_err(query: zenoh.Query, kind: str, text: str) -> None:
        try:
            query.reply_err(_error_payload(kind, text))
        except Exception as exc:
            log.debug("error reply failed: %s", exc)

    def destroy(self) -> None:
        self._destroyed = True
        try:
            self._queryable.undeclare()
        except Exception:
            pass  # already closed with the session


class _Call:
    """One outstanding query: collects replies on Zenoh's thread, completes the future at the end."""

    def __init__(self, client: Client[Any, Any], future: Future[Any], timeout: float, dict_form: bool) -> None:
        self.client = client
        self.future = future
        self.timeout = timeout
        self.dict_form = dict_form
        self.started = time.monotonic()
        self.errors: list[tuple[str, str] | None] = []

    def on_reply(self, reply: zenoh.Reply) -> None:
        if self.future.done():
            return
        if reply.ok is not None:
            try:
                result = self.client._decode_response(reply.ok.payload.to_bytes(), self.dict_form)
            except ServiceCallError as exc:
                self._finish(exc=exc)
                return
            self._finish(result=result)
        else:
            err = reply.err
            self.errors.append(decode_error(err.payload.to_bytes()) if err is not None else None)

    def on_done(self) -> None:
        if self.future.done():
            return
        name = self.client.service_name
        ours = [e for e in self.errors if e is not None]
        if ours:
            kind, text = ours[0]
            self._finish(exc=ServiceError(text, kind))
        elif self.errors or time.monotonic() - self.started >= self.timeout * 0.9:
            self._finish(exc=ServiceTimeout(f"service {name}: no reply within {self.timeout:g} s"))
        else:
            self._finish(exc=ServiceUnavailable(f"service {name}: no server"))

    def _finish(self, result: Any = None, exc: BaseException | None = None) -> None:
        try:
            if exc is not None:
                self.future.set_exception(exc)
            else:
                self.future.set_result(result)
        except Exception:
            pass  # cancelled or already completed by the other path


class Client(Generic[Req, Resp]):
    """``client.call(request, timeout)`` -> response, or a ServiceCallError subclass."""

    def __init__(self, context: EntityContext, name: str, key: str, request_type: type[Req],
                 response_type: type[Resp] | None, *, request_support: TypeSupport | None = None) -> None:
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
        self._querier = context.session.declare_querier(key)

    # -- discovery -------------------------------------------------------------------
    def service_is_ready(self) -> bool:
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
    def call(self, request: Req, timeout: float = 2.0) -> Resp:
        """Send ``request`` and wait for the response.

        Blocks only this thread: replies arrive on Zenoh's threads, so calling this from a
        callback of a single-threaded executor does not deadlock (unless the server is a
        service of the same executor, which then cannot run: ServiceTimeout).
        """
        if not self.service_is_ready():
            started = self.context.started
            grace = max(MATCH_WAIT_S, DISCOVERY_GRACE_S - (time.monotonic() - started))
            if not self.wait_for_service(min(timeout, grace)):
                raise ServiceUnavailable(f"service {self.service_name}: no server")
        future = self.call_async(request, timeout)
        try:
            return future.result(timeout + 2.0)  # Zenoh finalises at `timeout`; the margin is a backstop
        except FutureTimeout:
            raise ServiceTimeout(f"service {self.service_name}: no reply within {timeout:g} s") from None

    def call_async(self, request: Req, timeout: float = 2.0) -> "Future[Resp]":
        """Send ``request``; the Future completes on a Zenoh thread (keep done-callbacks short)."""
        if not isinstance(request, self.request_type):
            raise TypeError(f"service {self.service_name} client takes {self._req.name}, "
                            f"got {type(request).__name__}")
        return self._send(self._req.encode(request), timeout, dict_form=False)

    def _send(self, body: Any, timeout: float, dict_form: bool) -> Future[Any]:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 seconds, got {timeout!r}")
        self.context.check_open()
        future: Future[Any] = Future()
        call = _Call(self, future, timeout, dict_form)
        extra: dict[str, Any] = {}
        if self._resp is not None:
            extra = {"rt": self._resp.name, "rh": self._resp.hash}
        if dict_form:
            extra["form"] = "dict"
        payload = envelope.pack(self._req.name, self._req.hash, self.client_id,
                                next(self._seq), time.time_ns(), body, extra)
        self.context.session.get(self.key, zenoh.handlers.Callback(call.on_reply, call.on_done),
                              payload=payload, timeout=timeout, priority=zenoh.Priority.INTERACTIVE_HIGH)
        return future

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
        try:
            self._querier.undeclare()
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

    def create_client(self, name: str, request_type: type[Req], response_type: type[Resp]) -> Client[Req, Resp]:
        self._context.check_open()
        if not (isinstance(response_type, type) and issubclass(response_type, Message)):
            raise TypeError(f"create_client {name!r}: response type {response_type!r} is not a message type")
        client = Client(self._context, name, self.resolve_service_name(name), request_type, response_type)
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
