"""What protects a session's commands, said once at start-up by the companion and the GCS.

In the default profile a client id is a claim: any peer that reaches the session can copy a
GCS's id off its setpoints and command the drone. The apps say so in one WARNING line at start
(``UNAUTHENTICATED`` is in it, for tests and log searches); with ``--secure`` the line says
which protection is on instead (mTLS + ACL, this node's certificate and role), at INFO.
:func:`reaches_network` tells whether a session dials or listens beyond this host on purpose
(a multicast interface, a non-loopback connect endpoint): where the GCS asks for
``--insecure-ok`` before flying a mission without ``--secure``.

With ``--link-keys DIR`` every sample of the node's topics and services is sealed
(``zenoh_robot.wire.sealed``: ChaCha20-Poly1305 per sample, replay window, per-role keys, the client
id bound to the sealing GCS's key): the line says so at INFO, with the key ids (never the keys).
"""
from __future__ import annotations

import ipaddress
import logging
from typing import TYPE_CHECKING, Any

from zenoh_robot import SessionConfig
from zenoh_robot.session_config import SECURE_PROTOCOLS

if TYPE_CHECKING:
    from zenoh_robot.keyring import Keyring

UNAUTHENTICATED = "UNAUTHENTICATED"


def startup_line(config: SessionConfig, link_keys: Keyring | None = None, encrypt: bool = False) -> tuple[int, str]:
    """``(logging level, line)`` saying what protects commands and control on ``config`` (and, with
    ``link_keys``, the sealed samples of ``--link-keys``)."""
    if link_keys is not None:
        mode = "encrypted" if encrypt else "authenticated"
        ids = ", ".join(link_keys.key_ids())
        return logging.INFO, (f"link protection: per-sample AEAD (ChaCha20-Poly1305, {mode}), key ids {ids} of "
                              f"{link_keys.node!r} ({link_keys.directory}): every topic sample and command is sealed "
                              "by its sender's key; unsealed, replayed, another node's or revoked keys, and a client "
                              "id that is not the sealing GCS's are refused and counted")
    return _session_line(config)


def _session_line(config: SessionConfig) -> tuple[int, str]:
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


def log_startup_line(log: logging.Logger, config: SessionConfig, link_keys: Keyring | None = None,
                     encrypt: bool = False) -> None:
    level, line = startup_line(config, link_keys, encrypt)
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


def link_wire(keys_dir: str, node: str, encrypt: bool = False) -> tuple[Any, Keyring]:
    """``(wire format, keyring)`` for ``--link-keys DIR``: the envelope sealed with ``node``'s link keys
    (``DIR/<node>.json`` from ``zenoh-robot keys link``); the keyring is re-read on SIGHUP (and every
    ``refresh_s`` when a file changed). KeyringError (a ValueError) for a missing or open keyring."""
    import signal

    from zenoh_robot.keyring import Keyring
    from zenoh_robot.wire import ENVELOPE, sealed

    keyring = Keyring(keys_dir, node)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, lambda *_: _reload(keyring))
    return sealed(ENVELOPE, keyring, encrypt=encrypt), keyring


def _reload(keyring: Keyring) -> None:
    from zenoh_robot.keyring import KeyringError
    try:
        keyring.reload()
        logging.getLogger("drone_contract.link_protection").info("link keys re-read: %r", keyring)
    except KeyringError as exc:
        logging.getLogger("drone_contract.link_protection").warning("link keys not re-read: %s", exc)


# What a sealed format counts that is not a refusal: statistics of the normal flow (a duplicate is a
# repeat's expected copy, docs/security.md).
_NOT_REFUSALS = frozenset({"opened", "sealed", "duplicate", "epochs_forgotten"})


def link_refusals(wire: Any) -> dict[str, int] | None:
    """Sealed samples and calls this node refused, by reason (forged, replayed, not fresh: ``bad_tag``,
    ``replayed``, ``restarted``, ``expired``, ...), or None when its link is not sealed."""
    snapshot = getattr(wire, "snapshot", None)
    if snapshot is None:
        return None
    return {k: v for k, v in snapshot().items() if k not in _NOT_REFUSALS}


class RefusalWatch:
    """Tells the operator when sealed samples start being refused: a drone under attack (or a GCS whose
    keys are wrong) must show, not only count. :meth:`poll` returns the refusals since the last call that
    reported, by reason, at most once per ``interval_s``; None while nothing new was refused."""

    def __init__(self, wire: Any, interval_s: float = 5.0) -> None:
        self._wire = wire
        self._interval_s = interval_s
        self._reported: dict[str, int] = link_refusals(wire) or {}
        self._due = 0.0

    def total(self) -> int:
        return sum((link_refusals(self._wire) or {}).values())

    def poll(self, now: float) -> dict[str, int] | None:
        if now < self._due:
            return None
        current = link_refusals(self._wire)
        if not current:
            return None
        new = {k: v - self._reported.get(k, 0) for k, v in current.items() if v > self._reported.get(k, 0)}
        if not new:
            return None
        self._reported = current
        self._due = now + self._interval_s
        return new
