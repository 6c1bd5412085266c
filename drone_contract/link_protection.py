"""What protects a session's commands, said once at start-up by the companion and the GCS.

In the default profile a client id is a claim: any peer that reaches the session can copy a
GCS's id off its setpoints and command the drone. The apps say so in one WARNING line at start
(``UNAUTHENTICATED`` is in it, for tests and log searches); with ``--secure`` the line says
which protection is on instead (mTLS + ACL, this node's certificate and role), at INFO.
:func:`reaches_network` tells whether a session dials or listens beyond this host on purpose
(a multicast interface, a non-loopback connect endpoint): where the GCS asks for
``--insecure-ok`` before flying a mission without ``--secure``.
"""
from __future__ import annotations

import ipaddress
import logging

from zenoh_robot import SessionConfig
from zenoh_robot.session_config import SECURE_PROTOCOLS

UNAUTHENTICATED = "UNAUTHENTICATED"


def startup_line(config: SessionConfig) -> tuple[int, str]:
    """``(logging level, line)`` saying what protects commands and control on ``config``."""
    if config.secure:
        role = _role(config.secure, config.name or "")
        return logging.INFO, (f"link protection: mTLS + ACL (certificate {config.name!r}{role}, CA and roles in "
                              f"{config.secure}): only peers with a certificate of that CA and a role for this "
                              "drone may command it; plain links are refused")
    endpoints = config.listen + config.connect
    if endpoints and all(e.split("/", 1)[0] in SECURE_PROTOCOLS for e in endpoints):
        return logging.WARNING, (f"link protection: TLS as the session file configures it ({config.source}); "
                                 "not the mTLS + ACL of --secure: unless that file sets both, commands are "
                                 f"{UNAUTHENTICATED} (a peer can claim a GCS's client id); use --secure DIR")
    return logging.WARNING, (f"link protection: none: commands and control are {UNAUTHENTICATED} on this "
                             "session (any peer that reaches it can claim a GCS's client id and command the "
                             "drone); use --secure DIR (mTLS + ACL by role, keys from `zenoh-robot keys`)")


def log_startup_line(log: logging.Logger, config: SessionConfig) -> None:
    level, line = startup_line(config)
    log.log(level, "%s", line)


def reaches_network(config: SessionConfig) -> bool:
    """True if the session is meant to meet peers on another host: a multicast group on an
    interface, or a connect endpoint that is not loopback (a name counts as remote)."""
    if config.multicast:
        return True
    return any(not _loopback(e) for e in config.connect)


def _loopback(endpoint: str) -> bool:
    proto, _, rest = endpoint.partition("/")
    if proto in ("unixsock-stream", "unixpipe"):
        return True
    rest = rest.split("#", 1)[0].split("?", 1)[0]
    host = rest.rpartition(":")[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _role(keys_dir: str, name: str) -> str:
    from zenoh_robot import acl
    try:
        entry = acl.load_roles(keys_dir).get(name)
    except (acl.KeysError, OSError):
        return ""
    if entry is None:
        return ""
    return f", role {entry.role}" + (f" for {', '.join(entry.drones)}" if entry.drones else "")
