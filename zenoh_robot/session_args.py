"""The session flags every program shares, defined once (as zenoh-python's examples do).

:func:`add_session_arguments` adds ``--zenoh FILE``, ``-m/--mode``, ``-e/--connect``,
``-l/--listen``, ``--secure DIR``, ``--cert-name NAME``, ``--domain N``, ``--ros2`` and
``--ros-domain-id N`` to a parser; :func:`session_config_from_args` turns the parsed flags into a
:class:`SessionConfig`: the ``--zenoh`` file (or the program's default config), refined by the
other flags; :func:`wire_from_args` into the wire format of the program's nodes. Every default is
``argparse.SUPPRESS``, so a command may take the flags both before and after its operation
(``zenoh-robot topic --zenoh F echo /x`` and ``... echo /x --zenoh F``) without the absent one
overwriting the given one.
"""
from __future__ import annotations

import argparse
import dataclasses
import ipaddress
from collections.abc import Callable
from typing import Any

from .session_config import MAX_DOMAIN, MODES, SECURE_PROTOCOLS, SessionConfig, SessionConfigError, resolve_domain
from .wire import ENVELOPE, WireFormat, ros2_wire


def add_session_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the session flags to ``parser`` (read them back with :func:`session_config_from_args`)."""
    group = parser.add_argument_group("Zenoh session (--secure, --domain: docs/security.md)")
    hide = argparse.SUPPRESS
    group.add_argument("--zenoh", metavar="FILE", default=hide,
                       help="Zenoh session config (JSON5); the flags below refine it")
    group.add_argument("--mode", "-m", choices=MODES, default=hide, help="Zenoh mode (default: the config's, peer)")
    group.add_argument("--connect", "-e", action="append", default=hide, metavar="ENDPOINT",
                       help="also connect to ENDPOINT (e.g. tcp/127.0.0.1:7447, tls/10.0.0.1:7447); repeatable")
    group.add_argument("--listen", "-l", action="append", default=hide, metavar="ENDPOINT",
                       help="listen on ENDPOINT instead of the config's endpoints; repeatable")
    group.add_argument("--secure", metavar="DIR", default=hide,
                       help="keys directory from `zenoh-robot keys`: TLS/QUIC only, mutual auth, ACL by role")
    group.add_argument("--cert-name", metavar="NAME", default=hide,
                       help="this node's certificate in --secure DIR (default: the node's id)")
    group.add_argument("--domain", metavar="N", default=hide,
                       help=f"domain id 0..{MAX_DOMAIN} (env ZR_DOMAIN): systems in other domains never meet")
    group.add_argument("--ros2", action="store_true", default=hide,
                       help="speak ROS 2's wire (rmw_zenoh: CDR, @ros2_lv graph): see and talk to ROS 2 nodes "
                            "(docs/ros2.md)")
    group.add_argument("--ros-domain-id", metavar="N", type=int, default=hide,
                       help="ROS 2 domain id with --ros2 (implies it; default: env ROS_DOMAIN_ID, else 0)")


def wire_from_args(args: argparse.Namespace) -> WireFormat:
    """The wire format the flags ask for: ROS 2's (its domain: ``--ros-domain-id``, else env
    ``ROS_DOMAIN_ID``, else 0) with ``--ros2`` or ``--ros-domain-id``, else the envelope."""
    domain: int | None = getattr(args, "ros_domain_id", None)
    if not getattr(args, "ros2", False) and domain is None:
        return ENVELOPE
    return ros2_wire(domain)


def session_config_from_args(args: argparse.Namespace,
                             default: SessionConfig | Callable[[], SessionConfig] | None = None,
                             name: str | None = None) -> SessionConfig:
    """The session the flags of :func:`add_session_arguments` ask for.

    The base is the ``--zenoh`` file, else ``default`` (a config, or a function making one, called
    only without ``--zenoh``), else ``SessionConfig()``. ``--mode`` replaces its mode, ``--listen``
    its listen endpoints, ``--connect`` adds endpoints, ``--domain`` (else env ``ZR_DOMAIN``) sets
    the domain. Under ``--secure`` (certificate ``--cert-name``, else ``name``) the plain endpoints
    become their secure twins (tcp -> tls, unicast udp -> quic); a UDP multicast endpoint has no
    secure twin and is dropped (docs/security.md). Raises :class:`SessionConfigError`.
    """
    path = getattr(args, "zenoh", None)
    if path:
        try:
            config = SessionConfig.from_file(path)
        except SessionConfigError as exc:   # the flag too: a user may not know where the file came from
            raise SessionConfigError(f"--zenoh {exc}") from None
    elif callable(default):
        config = default()
    else:
        config = default if default is not None else SessionConfig()
    changes: dict[str, Any] = {"domain": resolve_domain(getattr(args, "domain", None))}
    mode = getattr(args, "mode", None)
    if mode:
        changes["mode"] = mode
    listen = list(getattr(args, "listen", None) or config.listen)
    connect = list(config.connect) + list(getattr(args, "connect", None) or [])
    secure = getattr(args, "secure", None)
    if secure:
        listen = [e for e in (secure_twin(x) for x in listen) if e] or ["tls/0.0.0.0:0"]
        connect = [e for e in (secure_twin(x) for x in connect) if e]
        changes.update(secure=secure, name=getattr(args, "cert_name", None) or name, shared_memory=False)
    changes.update(listen=listen, connect=connect)
    return dataclasses.replace(config, **changes)


def secure_twin(endpoint: str) -> str | None:
    """The TLS/QUIC endpoint ``--secure`` turns ``endpoint`` into; None for a multicast one (no secure twin)."""
    proto, _, rest = endpoint.partition("/")
    if proto in SECURE_PROTOCOLS:
        return endpoint
    host = rest.split("#", 1)[0].rpartition(":")[0].strip("[]")
    if proto == "udp":
        try:
            if ipaddress.ip_address(host).is_multicast:
                return None
        except ValueError:
            pass
        # Best-effort samples as QUIC datagrams (as on UDP), reliable ones on a stream: on one
        # stream every sample waits behind each retransmission (docs/security.md, measured).
        # "auto" falls back to the stream alone against a peer that does not offer it.
        return "quic/" + rest.split("#", 1)[0].split("?", 1)[0] + "?mixed_rel=auto"
    return "tls/" + rest if proto == "tcp" else None
