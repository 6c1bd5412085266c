"""Whether a session's connect endpoints were reached: a peer dialling an endpoint where nothing
listens opens anyway (Zenoh keeps retrying in the background), so a typo in ``-e`` or a router that
is not running would otherwise look like an empty network (issue #39).

An endpoint counts as reached when one of the session's links goes to its address. A link can be
missing although the endpoint is up: the peer behind it may have dialled us first (multicast
scouting) and Zenoh then keeps that transport and drops ours. So before calling an endpoint
unreached, a stream endpoint (tcp, tls, ws) is probed with a plain TCP connect, and a datagram one
(udp, quic), which cannot be probed that way, counts as reached once the session has any peer or router.
"""
from __future__ import annotations

import ipaddress
import socket
import time
from collections.abc import Iterable

import zenoh

from .session_config import _ENDPOINT

_STREAM_PROTOCOLS = ("tcp", "tls", "ws")
_Address = tuple[str, str, int]      # (protocol, ip, port)


def unreached_endpoints(session: zenoh.Session, endpoints: Iterable[str], wait_s: float = 0.5) -> list[str]:
    """Those of ``endpoints`` (connect endpoints of ``session``) that nothing answers, in their order. A
    stream endpoint is judged at once (its link, else the probe); a datagram one is given up to ``wait_s``."""
    given = list(endpoints)
    linked = _link_addresses(session)
    pending = [e for e in given if not _is_multicast(e) and not _addresses(e) & linked]
    unreached = {e for e in pending if _protocol(e) in _STREAM_PROTOCOLS and not _stream_answers(e)}
    datagram = [e for e in pending if _protocol(e) not in _STREAM_PROTOCOLS]
    deadline = time.monotonic() + wait_s
    while datagram and not _has_neighbours(session) and time.monotonic() < deadline:
        time.sleep(0.05)
        linked = _link_addresses(session)
        datagram = [e for e in datagram if not _addresses(e) & linked]
    if datagram and not _has_neighbours(session):
        unreached.update(datagram)
    return [e for e in given if e in unreached]


def _split(endpoint: str) -> tuple[str, str, int] | None:
    m = _ENDPOINT.match(endpoint.strip())
    if not m:
        return None
    host, _, port = m["addr"].rpartition(":")
    if not port.isdigit():
        return None
    return m["proto"], host.strip("[]"), int(port)


def _is_multicast(endpoint: str) -> bool:
    parts = _split(endpoint)
    if parts is None:
        return False
    try:
        return ipaddress.ip_address(parts[1]).is_multicast
    except ValueError:
        return False


def _addresses(endpoint: str) -> set[_Address]:
    parts = _split(endpoint)
    if parts is None:
        return set()
    proto, host, port = parts
    try:
        infos = socket.getaddrinfo(host, port, proto=socket.IPPROTO_TCP)
    except (OSError, UnicodeError):   # a name that does not resolve reaches nothing
        return set()
    return {(proto, str(ipaddress.ip_address(str(info[4][0]).split("%")[0])), port) for info in infos}


def _link_addresses(session: zenoh.Session) -> set[_Address]:
    out: set[_Address] = set()
    for link in session.info.links():
        parts = _split(str(link.dst))
        if parts is None:
            continue
        try:
            out.add((parts[0], str(ipaddress.ip_address(parts[1].split("%")[0])), parts[2]))
        except ValueError:
            continue
    return out


def _protocol(endpoint: str) -> str:
    parts = _split(endpoint)
    return parts[0] if parts is not None else ""


def _has_neighbours(session: zenoh.Session) -> bool:
    return bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))


def _stream_answers(endpoint: str) -> bool:
    """Whether something accepts a TCP connection at a stream endpoint; False for any other endpoint."""
    parts = _split(endpoint)
    if parts is None or parts[0] not in _STREAM_PROTOCOLS:
        return False
    try:
        with socket.create_connection((parts[1], parts[2]), timeout=0.3):
            return True
    except OSError:
        return False
