"""Services on rmw_zenoh's wire: what a node whose wire format is ROS 2's (``wire.name == "ros2"``)
serves and calls, so rmw_zenoh nodes (and zenoh-ros2-sdk) call our services and we call theirs.

- Key: ``<domain>/<service without the leading slash>/<pkg>::srv::dds_::<Srv>_/RIHS01_<hash>``; a type
  or hash mismatch is a different key, so no call at all (as between two rmw_zenoh nodes).
- A server is a complete queryable on that key; a client a Zenoh get (target ALL_COMPLETE, no
  consolidation). Payloads are CDR with the 4-byte encapsulation header; the types, their codec and
  the service hash are ``zenoh_robot.ros2``'s (``ros2_service_type``), the attachment, names and
  tokens the ROS 2 wire format's (``zenoh_robot.wire.ros2``): this module is the protocol only.
- Request and reply carry the 33-byte attachment: int64 LE sequence, int64 LE source stamp (ns),
  the byte 16, a 16-byte GID. The client sends its own GID and a per-client sequence; the reply
  carries the same sequence and GID (the request id) and the server's stamp.
- A request without that attachment is answered with ``reply_err``; one in the labelled format of
  rmw_zenoh Jazzy <= 0.2.3 is named as such, in the reply and in one warning per peer.
- Graph: ``SS`` / ``SC`` liveliness tokens written by the node's ROS 2 graph format (wire/ros2.py), naming the
  fully qualified service (``%zr%set_flag``, what rmw_zenoh's graph matches a client's name against), with
  the services' QoS (reliable, volatile, keep last 10) written out; an entity's GID (the client's, in
  its requests) is XXH3-128 of its token, as rmw_zenoh's.

Threads: the queryable callback runs on Zenoh's thread and only hands the query to the node's
executor, where the handler runs and the reply goes out (a handler may return a Future: the reply
then goes from the completing thread). A client's call blocks only its caller.
"""
from __future__ import annotations

import itertools
import logging
import secrets
import threading
import time
from collections.abc import Iterable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import zenoh

from .. import names
from ..context import EntityContext
from ..message import Message
from ..ratelimit import RateLimitedLog
from ..wire import MalformedSample
from ..wire.ros2 import (
    ADMIN_SPACE,
    CLIENT,
    SERVICE,
    LegacyAttachment,
    pack_attachment,
    parse_any_token,
    unpack_attachment,
)
from .errors import ServiceCallError, ServiceError, ServiceTimeout, ServiceUnavailable

if TYPE_CHECKING:
    from ..ros2 import Ros2ServiceType

Req = TypeVar("Req", bound=Message)
Resp = TypeVar("Resp", bound=Message)

log = logging.getLogger("zenoh_robot.services")

HUMBLE_HASH = "TypeHashNotSupported"          # what Humble's rmw_zenoh puts where the type hash goes
ZENOH_TIMEOUT = "Timeout"                     # the error reply Zenoh itself gives a query that runs out of time
MAX_REQUEST_BYTES = 16 << 20


def service_data_key(domain_id: int, service_name: str, srv: Ros2ServiceType) -> str:
    """``0/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/RIHS01_...`` for ``/add_two_ints``."""
    return f"{domain_id}/{service_name.strip('/')}/{srv.dds_name}/{srv.hash}"


class Ros2ServiceInfo:
    """A service server or client announced on the ROS 2 graph (an ``SS``/``SC`` token)."""

    __slots__ = ("kind", "zid", "node_namespace", "node_name", "service_name", "service_type", "type_hash")

    def __init__(self, kind: str, zid: str, node_namespace: str, node_name: str, service_name: str,
                 service_type: str, type_hash: str) -> None:
        self.kind, self.zid = kind, zid
        self.node_namespace, self.node_name = node_namespace, node_name
        self.service_name, self.service_type, self.type_hash = service_name, service_type, type_hash

    @property
    def humble(self) -> bool:
        """Announced by ROS 2 Humble's rmw_zenoh: no type hash, so no call can match Jazzy or newer."""
        return self.type_hash == HUMBLE_HASH

    def __repr__(self) -> str:
        return (f"Ros2ServiceInfo({self.kind} {self.service_name} [{self.service_type}] "
                f"node {self.node_namespace.rstrip('/')}/{self.node_name})")


def parse_service_token(key: str) -> Ros2ServiceInfo:
    """An ``SS``/``SC`` token back into what it announces; ValueError for any other key."""
    token = parse_any_token(key)
    if token.kind not in (SERVICE, CLIENT):
        raise ValueError(f"not a ROS 2 service token: {key!r}")
    return Ros2ServiceInfo(token.kind, token.zid, token.namespace, token.node, token.name,
                           token.type_name or token.raw_type, token.type_hash)


def service_infos(keys: Iterable[str]) -> list[Ros2ServiceInfo]:
    """The servers and clients among ``keys`` (liveliness token keys), sorted; other keys are skipped."""
    found: list[Ros2ServiceInfo] = []
    for key in keys:
        try:
            found.append(parse_service_token(key))
        except ValueError:
            continue
    return sorted(found, key=lambda i: (i.service_name, i.kind, i.node_namespace, i.node_name))


def ros2_services(session: zenoh.Session, domain_id: int, timeout: float = 1.0,
                  quiet: float = 0.3) -> list[Ros2ServiceInfo]:
    """Every service server and client on the ROS 2 graph of ``domain_id``.

    One liveliness query right after a session opens answers with the tokens Zenoh has delivered so
    far, which may be part of them: a subscriber with history collects them instead, until none has
    come for ``quiet`` seconds (at most ``timeout``).
    """
    keys: set[str] = set()
    changed = threading.Condition()
    arrivals = [0]

    def on_token(sample: Any) -> None:
        with changed:
            if sample.kind == zenoh.SampleKind.PUT:
                keys.add(str(sample.key_expr))
            else:
                keys.discard(str(sample.key_expr))
            arrivals[0] += 1
            changed.notify_all()

    sub = session.liveliness().declare_subscriber(f"{ADMIN_SPACE}/{domain_id}/**", on_token, history=True)
    try:
        end = time.monotonic() + timeout
        with changed:
            while True:
                seen = arrivals[0]
                left = end - time.monotonic()
                if left <= 0:
                    break
                changed.wait(min(quiet, left))
                if arrivals[0] == seen:     # a quiet spell: what the network had has arrived
                    break
            now = list(keys)
    finally:
        try:
            sub.undeclare()
        except Exception:
            pass   # the session closed under us: what was collected stands
    return service_infos(now)


def _declare_token(context: EntityContext, kind: str, service_name: str, srv: Ros2ServiceType) -> tuple[Any, bytes]:
    """The entity's SS/SC token (the node's ROS 2 graph format writes it, so its node id is the node's)
    and its GID: XXH3-128 of the token, as rmw_zenoh makes it."""
    from ..qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from ..wire.ros2 import Ros2Graph, token_gid

    graph = context.wire.graph
    if not isinstance(graph, Ros2Graph):
        raise TypeError(f"service {service_name}: a ROS 2 service needs a node on the ROS 2 wire, not {context.wire!r}")
    zid = str(context.session.info.zid())
    qos = QoSProfile(ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST, 10)
    key = graph.entity_token(kind, zid, secrets.randbits(63), "/" + context.namespace.strip("/"),
                                          context.node_name, service_name, srv.name, srv.hash, qos)
    return context.session.liveliness().declare_token(key), token_gid(key)


class _PeerWarnings:
    """One warning per peer and problem (a peer re-sending bad requests must not flood the log)."""

    MAX = 256

    def __init__(self) -> None:
        self._seen: set[tuple[str, str]] = set()
        self._lock = threading.Lock()

    def once(self, peer: str, problem: str, text: str) -> None:
        with self._lock:
            if (peer, problem) in self._seen or len(self._seen) >= self.MAX:
                return
            self._seen.add((peer, problem))
        log.warning("%s", text)


class _Ros2Endpoint:
    """What a server and a client on the ROS 2 wire both are: a service name, its type and data key."""

    def __init__(self, context: EntityContext, name: str, srv: Ros2ServiceType) -> None:
        self.context = context
        self.srv = srv
        self.name = name
        self.service_name = names.resolve_topic(name, context.namespace, context.node_name)
        self.key = service_data_key(int(getattr(context.wire, "domain_id", 0)), self.service_name, srv)
        self.request_type = srv.request
        self.response_type = srv.response


class Ros2Service(_Ros2Endpoint, Generic[Req, Resp]):
    """A server on the ROS 2 wire: ``handler(request) -> response`` (or a Future of it) on the executor."""

    def __init__(self, context: EntityContext, name: str, srv: Ros2ServiceType,
                 handler: Any) -> None:
        if not callable(handler):
            raise TypeError(f"create_service {name!r}: handler must be callable")
        super().__init__(context, name, srv)
        self.handler = handler
        self.served = 0
        self.errors = 0
        self.bad_requests = 0
        self.legacy_requests = 0
        self._lock = threading.Lock()
        self._destroyed = False
        self._warnings = _PeerWarnings()
        self._rlog = RateLimitedLog(log)
        self._queryable = context.session.declare_queryable(self.key, self._on_query, complete=True)
        self._token, self.gid = _declare_token(context, "SS", self.service_name, srv)

    # Zenoh's thread: check the envelope of the call, hand the rest over.
    def _on_query(self, query: zenoh.Query) -> None:
        if self._destroyed:
            query.drop()
            return
        attachment = query.attachment
        try:
            seq, _stamp, gid = unpack_attachment(attachment.to_bytes() if attachment is not None else None)
        except MalformedSample as exc:
            legacy = isinstance(exc, LegacyAttachment)
            with self._lock:
                self.bad_requests += 1
                self.legacy_requests += int(legacy)
            if not legacy:   # a legacy peer is named once by zenoh_robot.ros2.compat, for topics and services alike
                self._warnings.once(str(query.key_expr), "attachment",
                                    f"service {self.service_name}: a request with {exc}: not answered with data")
            self._reply_err(query, f"service {self.service_name}: {exc}")
            return
        payload = query.payload
        data = payload.to_bytes() if payload is not None else b""
        if len(data) > MAX_REQUEST_BYTES:
            with self._lock:
                self.bad_requests += 1
            self._reply_err(query, f"service {self.service_name}: request of {len(data)} bytes is over the limit")
            return
        if not self.context.executor.call_soon(lambda: self._run(query, data, seq, gid)):
            self._reply_err(query, f"service {self.service_name}: server queue full, request dropped")

    def _run(self, query: zenoh.Query, data: bytes, seq: int, gid: bytes) -> None:
        try:
            request = self.srv.decode_request(data)
        except Exception as exc:
            with self._lock:
                self.bad_requests += 1
            self._rlog.warning("bad_request", "service %s: refused a request: %s", self.service_name, exc)
            self._reply_err(query, f"service {self.service_name}: cannot decode {self.srv.name}_Request: {exc}")
            return
        try:
            response = self.handler(request)
        except Exception as exc:
            self._handler_failed(query, exc)
            return
        if isinstance(response, Future):
            response.add_done_callback(lambda done: self._settle(query, done, seq, gid))
            return
        self._reply(query, response, seq, gid)

    def _settle(self, query: zenoh.Query, done: Future[Any], seq: int, gid: bytes) -> None:
        try:
            response = done.result()
        except BaseException as exc:  # noqa: BLE001  (cancelled too: the caller hears it)
            self._handler_failed(query, exc)
            return
        self._reply(query, response, seq, gid)

    def _reply(self, query: zenoh.Query, response: Any, seq: int, gid: bytes) -> None:
        try:
            if not isinstance(response, self.response_type):
                raise TypeError(f"handler returned {type(response).__name__}, not {self.srv.name}_Response")
            payload = self.srv.encode_response(response)
        except Exception as exc:
            self._handler_failed(query, exc)
            return
        with self._lock:
            self.served += 1
        try:
            # The request id (seq, client GID) goes back so the client matches the reply; the stamp is ours.
            query.reply(self.key, payload, attachment=pack_attachment(seq, time.time_ns(), gid))
        except Exception as exc:   # the querier may have given up
            log.debug("service %s: reply failed: %s", self.service_name, exc)
        finally:
            self._drop(query)

    def _handler_failed(self, query: zenoh.Query, exc: BaseException) -> None:
        with self._lock:
            self.errors += 1
        self._rlog.warning("handler", "service %s: handler raised %s: %s", self.service_name, type(exc).__name__, exc)
        self._reply_err(query, f"service {self.service_name}: handler raised {type(exc).__name__}: {exc}")

    def _reply_err(self, query: zenoh.Query, text: str) -> None:
        try:
            query.reply_err(text.encode())
        except Exception as exc:
            log.debug("service %s: error reply failed: %s", self.service_name, exc)
        finally:
            self._drop(query)

    @staticmethod
    def _drop(query: zenoh.Query) -> None:
        try:
            query.drop()     # the querier sees the call finalised at once
        except Exception:
            pass

    def describe(self) -> dict[str, Any]:
        return {"service": self.service_name, "node": self.context.fully_qualified_name,
                "type": self.srv.name, "type_hash": self.srv.hash}

    def destroy(self) -> None:
        self._destroyed = True
        for handle in (self._token, self._queryable):
            try:
                handle.undeclare()
            except Exception:
                pass   # already closed with the session


class Ros2Client(_Ros2Endpoint, Generic[Req, Resp]):
    """A client on the ROS 2 wire: ``call(request, timeout)`` -> response, or a ServiceCallError subclass."""

    def __init__(self, context: EntityContext, name: str, srv: Ros2ServiceType) -> None:
        super().__init__(context, name, srv)
        self._seq = itertools.count(1)
        self.attempts = 0
        self.bad_replies = 0
        self._querier = context.session.declare_querier(self.key, target=zenoh.QueryTarget.ALL_COMPLETE,
                                                        consolidation=zenoh.ConsolidationMode.NONE)
        self._token, self.gid = _declare_token(context, "SC", self.service_name, srv)

    def service_is_ready(self) -> bool:
        try:
            status: Any = self._querier.matching_status
            return bool(status.matching)
        except Exception:
            return False

    def wait_for_service(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.service_is_ready():
            if self.context.closed or (deadline is not None and time.monotonic() >= deadline):
                return False
            time.sleep(0.02)
        return True

    def call(self, request: Req, timeout: float = 2.0) -> Resp:
        """Send ``request`` and wait for the response (no server known within the discovery grace:
        ServiceUnavailable; no reply in time: ServiceTimeout; the server's error: ServiceError)."""
        from .client import DISCOVERY_GRACE_S, MATCH_WAIT_S

        if not self.service_is_ready():
            grace = max(MATCH_WAIT_S, DISCOVERY_GRACE_S - (time.monotonic() - self.context.started))
            if not self.wait_for_service(min(timeout, grace)):
                raise ServiceUnavailable(f"service {self.service_name} ({self.srv.name}): no server")
        future = self.call_async(request, timeout)
        try:
            return future.result(timeout + 2.0)
        except FutureTimeout:
            raise ServiceTimeout(f"service {self.service_name}: no reply within {timeout:g} s") from None

    def call_async(self, request: Req, timeout: float = 2.0) -> Future[Resp]:
        """Send ``request``; the Future completes on a Zenoh thread (keep done-callbacks short)."""
        if not isinstance(request, self.request_type):
            raise TypeError(f"service {self.service_name} client takes {self.srv.name}_Request, "
                            f"got {type(request).__name__}")
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 seconds, got {timeout!r}")
        self.context.check_open()
        payload = self.srv.encode_request(request)
        seq = next(self._seq)
        future: Future[Resp] = Future()
        errors: list[str] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if future.done():
                return
            if reply.ok is None:
                err = reply.err
                text = err.payload.to_bytes().decode("utf-8", "replace") if err is not None else "error"
                if text == ZENOH_TIMEOUT:
                    return      # Zenoh's own: the query ran out of time (a ServiceTimeout), not the server's error
                errors.append(text)
                return
            sample = reply.ok
            attachment = sample.attachment
            try:
                got_seq, _stamp, got_gid = unpack_attachment(attachment.to_bytes() if attachment is not None else None)
                if (got_seq, got_gid) != (seq, self.gid):
                    raise MalformedSample(f"reply to request {got_seq}, not {seq}")
                result: Any = self.srv.decode_response(sample.payload.to_bytes())
            except Exception as exc:
                self.bad_replies += 1
                errors.append(f"bad reply: {exc}")
                return
            complete_future(future, result=result)

        def on_done() -> None:
            if future.done():
                return
            if errors:
                complete_future(future, exc=ServiceError(f"service {self.service_name}: {errors[-1]}", "handler"))
            else:
                complete_future(future, exc=ServiceTimeout(
                    f"service {self.service_name}: no reply within {timeout:g} s"))

        self.attempts += 1
        try:
            # The session's get, not the querier's: it takes this call's timeout (the querier keeps discovery).
            self.context.session.get(self.key, zenoh.handlers.Callback(on_reply, on_done), payload=payload,
                                     attachment=pack_attachment(seq, time.time_ns(), self.gid), timeout=timeout,
                                     encoding=zenoh.Encoding("application/cdr"),
                                     target=zenoh.QueryTarget.ALL_COMPLETE,
                                     consolidation=zenoh.ConsolidationMode.NONE)
        except Exception as exc:
            complete_future(future, exc=ServiceCallError(f"service {self.service_name}: cannot send: {exc}"))
        return future

    def destroy(self) -> None:
        for handle in (self._token, self._querier):
            try:
                handle.undeclare()
            except Exception:
                pass


def complete_future(future: Future[Any], result: Any = None, exc: BaseException | None = None) -> None:
    """Set ``future``'s result or exception unless a racing path (reply, timeout) already did."""
    try:
        if exc is not None:
            future.set_exception(exc)
        else:
            future.set_result(result)
    except Exception:
        pass   # completed already by the other path
