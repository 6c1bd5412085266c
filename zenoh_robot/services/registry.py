"""A node's services and clients (the Services registry), and calls by name without Python types.

``describe_services`` asks servers for their names and types; ``call_dict`` calls a service with
a mapping (the CLI uses both).
"""
from __future__ import annotations

import threading
from concurrent.futures import TimeoutError as FutureTimeout
from typing import TYPE_CHECKING, Any, TypeVar, cast

import msgpack
import zenoh

from ..context import EntityContext
from ..message import Message, TypeSupport
from .client import DISCOVERY_GRACE_S, Client
from .errors import ServiceTimeout, ServiceUnavailable
from .keys import DESCRIBE_PARAM, SERVICE_PREFIX, service_key
from .retry import _DEFAULT, Retry
from .ros2 import Ros2Client, Ros2Service
from .service import Handler, Service

if TYPE_CHECKING:
    from ..node import Node
    from ..ros2 import Ros2ServiceType

Req = TypeVar("Req", bound=Message)
Resp = TypeVar("Resp", bound=Message)


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
        self.services: list[Service[Any, Any]] = []     # a Ros2Service among them is typed as one too
        self.clients: list[Client[Any, Any]] = []

    # The seam: the node's wire format decides how a service travels. The envelope's services are
    # Service/Client (this package's doc); on ROS 2's wire, rmw_zenoh's (ros2.py).
    def _ros2_service(self, what: str, name: str, request_type: Any, response_type: Any) -> Ros2ServiceType | None:
        """The ROS 2 service type whose halves these are, on a ROS 2 node; else None: other types (the
        parameter service, the drone contract's commands) keep the envelope on every node."""
        if getattr(self._context.wire, "name", "") != "ros2":
            return None
        from ..ros2.services import service_type_of  # only ROS 2 nodes load the ros2 package

        return service_type_of(request_type, response_type)

    def resolve_service_name(self, name: str) -> str:
        """The Zenoh key of service ``name``: ``arm`` in ``uav1`` -> ``@srv/uav1/arm``."""
        return service_key(name, self._context.namespace, self._context.node_name)

    def create_service(self, name: str, request_type: type[Req], response_type: type[Resp],
                       handler: Handler[Req, Resp]) -> Service[Req, Resp]:
        """On a ROS 2 node with a ROS 2 service type's halves, the server is a Ros2Service (rmw_zenoh's
        wire, the same surface less the envelope's retry counters); typed as Service for the callers."""
        self._context.check_open()
        ros2 = self._ros2_service("create_service", name, request_type, response_type)
        if ros2 is not None:
            server = cast("Service[Req, Resp]", Ros2Service(self._context, name, ros2, handler))
            with self._lock:
                self.services.append(server)
            return server
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
        ros2 = self._ros2_service("create_client", name, request_type, response_type)
        if ros2 is not None:
            # call/call_async/service_is_ready/wait_for_service/destroy as Client's
            ros2_client = cast("Client[Req, Resp]", Ros2Client(self._context, name, ros2))
            with self._lock:
                self.clients.append(ros2_client)
            return ros2_client
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
