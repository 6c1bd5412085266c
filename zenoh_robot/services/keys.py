"""Where services live on Zenoh: the ``@srv`` key of a service name, and the verbatim chunks below it.

``@srv``, ``@rq`` and ``@rp`` are verbatim chunks: ``*`` and ``**`` never match them, so topic
subscribers never see service traffic and ``@srv/**`` (service listing) never sees put-carried calls.
"""
from __future__ import annotations

from .. import names

SERVICE_PREFIX = "@srv"
DESCRIBE_PARAM = "zr_describe"    # selector parameter: the query asks for the service's name and types
REQUEST_CHUNK = "@rq"    # multicast sessions: requests are put on <service key>/@rq
REPLY_CHUNK = "@rp"      # ... and replies on <service key>/@rp/<client_id>, attachment: seq (8 bytes) + flag


def service_key(name: str, namespace: str = "", node_name: str = "") -> str:
    """The Zenoh key of a service name as seen from a node (see the package doc)."""
    return f"{SERVICE_PREFIX}/{names.resolve_topic(name, namespace, node_name)}"


def service_name_of_key(key: str) -> str:
    """``@srv/uav1/arm`` -> ``/uav1/arm``."""
    prefix = SERVICE_PREFIX + "/"
    return "/" + (key[len(prefix):] if key.startswith(prefix) else key)
