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
  estimate (``client.set_loss``, e.g. fed by a LossMonitor; 50 % when none) and the deadline
  (zenoh_robot/services/call_plan.py): a request copy every 10-50 ms, and on a multicast session the number of
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

ROS 2's wire: on a node whose wire format is ROS 2's, a service whose types are the halves of a
ROS 2 service type (``zenoh_robot.ros2.ros2_service_type("example_interfaces/srv/AddTwoInts")``)
speaks rmw_zenoh's service protocol instead (ros2.py has it); other types keep the envelope.

Modules, one job each: errors (the exceptions, the error payload), keys (service keys, the
verbatim chunks), retry (RetryPolicy, AdaptiveRetry, the presets), scheduler (the retry thread),
idempotency (the server's cache of recent requests), multicast (the put-carried transport's
attachments and publishers), service (Service), client (Client and its calls), registry (a node's
Services, describe_services, call_dict; the seam picking a service's wire), ros2 (rmw_zenoh's service
protocol over the ROS 2 wire format's attachment and tokens; the types are ``zenoh_robot.ros2``'s).
"""
from __future__ import annotations

from .client import DISCOVERY_GRACE_S, MATCH_WAIT_S, Client
from .errors import ServiceCallError, ServiceError, ServiceTimeout, ServiceUnavailable, decode_error
from .idempotency import IdempotencyCache, Reply, Responder
from .keys import DESCRIBE_PARAM, REPLY_CHUNK, REQUEST_CHUNK, SERVICE_PREFIX, service_key, service_name_of_key
from .multicast import MAX_REPLY_PUBLISHERS, MULTICAST_REPLY_COPIES
from .registry import Services, call_dict, describe_services
from .retry import (
    ADAPTIVE_RETRY,
    RESILIENT_RETRY,
    UNICAST_COMMAND_RETRY,
    AdaptiveRetry,
    Retry,
    RetryPolicy,
    command_retry,
)
from .ros2 import (
    Ros2Client,
    Ros2Service,
    Ros2ServiceInfo,
    parse_service_token,
    ros2_services,
    service_data_key,
    service_infos,
)
from .service import MAX_REQUEST_BYTES, Service

__all__ = [
    "ADAPTIVE_RETRY",
    "DESCRIBE_PARAM",
    "DISCOVERY_GRACE_S",
    "MATCH_WAIT_S",
    "MAX_REPLY_PUBLISHERS",
    "MAX_REQUEST_BYTES",
    "MULTICAST_REPLY_COPIES",
    "REPLY_CHUNK",
    "REQUEST_CHUNK",
    "RESILIENT_RETRY",
    "SERVICE_PREFIX",
    "UNICAST_COMMAND_RETRY",
    "AdaptiveRetry",
    "Client",
    "IdempotencyCache",
    "Reply",
    "Responder",
    "Retry",
    "RetryPolicy",
    "Ros2Client",
    "Ros2Service",
    "Ros2ServiceInfo",
    "Service",
    "ServiceCallError",
    "ServiceError",
    "ServiceTimeout",
    "ServiceUnavailable",
    "Services",
    "call_dict",
    "command_retry",
    "decode_error",
    "describe_services",
    "parse_service_token",
    "ros2_services",
    "service_infos",
    "service_data_key",
    "service_key",
    "service_name_of_key",
]
