"""rmw_zenoh peers of versions that exchange no data with Jazzy 0.2.4+ (and with us): named, not silent.

- ROS 2 Humble's rmw_zenoh has no type hashes: its tokens carry ``TypeHashNotSupported`` where
  the ``RIHS01_…`` hash goes, and so do its data keys, which therefore never meet ours.
- rmw_zenoh Jazzy <= 0.2.3 put a labelled attachment (``sequence_number``, ``source_timestamp``,
  ``source_gid``) on each sample; current rmw_zenoh, and we, read only the 33-byte form.

Either is counted (:data:`COUNTERS`, shown by ``zenoh-robot topic info`` and ``doctor``) and said as
a warning once per peer (per zid for Humble, per source GID for the legacy attachment), by name,
behind a rate limit, so a peer cannot flood the log however many tokens or samples it sends.
The ROS 2 wire format (``zenoh_robot.wire.ros2``) calls :func:`note_token` for every ``@ros2_lv``
token it reads and :func:`note_legacy_attachment` for each labelled attachment it refuses.

Thread safe: called from Zenoh's threads and the executors; the tables are bounded.
"""
from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from dataclasses import dataclass

from ..ratelimit import RateLimiter

log = logging.getLogger("zenoh_robot.ros2")

HUMBLE_TYPE_HASH = "TypeHashNotSupported"
MAX_PEERS = 1024
_LEGACY_GID_LABEL = b"source_gid"


@dataclass
class CompatCounters:
    humble_tokens: int = 0          # @ros2_lv tokens without a type hash (rmw_zenoh Humble)
    humble_peers: int = 0           # distinct sessions (zids) that announced them
    legacy_attachments: int = 0     # samples or requests with rmw_zenoh <= 0.2.3's labelled attachment
    legacy_peers: int = 0           # distinct source GIDs (or topics, when no GID could be read)


COUNTERS = CompatCounters()
_LOCK = threading.Lock()
_NAMED: OrderedDict[str, None] = OrderedDict()     # peers already said, oldest forgotten first
_LIMIT = RateLimiter(burst=5, interval=10.0)        # across peers: many at once cannot flood either


def humble_token(key: str) -> bool:
    """Whether ``key`` is an ``@ros2_lv`` entity token of rmw_zenoh Humble (no type hash)."""
    parts = key.split("/")
    return len(parts) == 13 and parts[0] == "@ros2_lv" and parts[11] == HUMBLE_TYPE_HASH


def _first_time(peer: str) -> bool:
    with _LOCK:
        if peer in _NAMED:
            return False
        _NAMED[peer] = None
        if len(_NAMED) > MAX_PEERS:
            _NAMED.popitem(last=False)
        return True


def _count(kind: str, peer: str) -> bool:
    """Count one ``kind`` (humble, legacy) occurrence from ``peer``; True when it is to be said now: the
    first from that peer, and within the warnings' rate limit across peers."""
    with _LOCK:
        setattr(COUNTERS, _OCCURRENCES[kind], getattr(COUNTERS, _OCCURRENCES[kind]) + 1)
    if not _first_time(f"{kind}/{peer}"):
        return False
    with _LOCK:
        setattr(COUNTERS, f"{kind}_peers", getattr(COUNTERS, f"{kind}_peers") + 1)
    return _LIMIT.admit(kind) is not None


_OCCURRENCES = {"humble": "humble_tokens", "legacy": "legacy_attachments"}


def note_token(key: str) -> bool:
    """Count and name a Humble token (True); any other key: nothing (False)."""
    if not humble_token(key):
        return False
    parts = key.split("/")
    zid, kind, ns, node, name, dds_type = parts[2], parts[5], parts[7], parts[8], parts[9], parts[10]
    if _count("humble", zid):
        who = f"{('/' + ns.replace('%', '/').strip('/')).rstrip('/')}/{node}"
        log.warning("ROS 2 Humble peer %s (session %s, %s %s of %s): rmw_zenoh on Humble has no type hashes "
                    "(%s), so no data is exchanged with it from Jazzy or newer, nor from zenoh-robot; run the "
                    "peer on Jazzy 0.2.4+ (docs/ros2.md)", who, zid, kind, name.replace("%", "/"), dds_type,
                    HUMBLE_TYPE_HASH)
    return True


def legacy_gid(data: bytes | memoryview) -> str | None:
    """The hex GID in a labelled attachment, if one follows its ``source_gid`` label."""
    buf = bytes(data)
    at = buf.find(_LEGACY_GID_LABEL)
    if at < 0:
        return None
    gid = buf[at + len(_LEGACY_GID_LABEL):][-16:]
    return gid.hex() if len(gid) == 16 else None


def note_legacy_attachment(data: bytes | memoryview, where: str) -> None:
    """Count and name a sample (or request) on ``where`` with rmw_zenoh <= 0.2.3's labelled attachment."""
    peer = legacy_gid(data) or where
    if _count("legacy", peer):
        log.warning("rmw_zenoh <= 0.2.3 peer (GID %s) on %s: its labelled attachment (sequence_number, "
                    "source_timestamp, source_gid) is refused, as current rmw_zenoh refuses it; its samples are "
                    "dropped and counted: update the peer to rmw_zenoh 0.2.4+ (docs/ros2.md)", peer, where)


def summary() -> dict[str, int]:
    with _LOCK:
        return dict(vars(COUNTERS))
