"""Link keys: the symmetric keys that seal samples (``zenoh_robot.wire.sealed``), as one node holds them.

A node's keyring is one JSON file, ``<dir>/<node>.json`` (0600, made by ``zenoh-robot keys link``)::

    {"node": "uav1", "keys": [{"id": "1a2b3c4d", "sender": "gcs1", "role": "gcs", "scope": "uav1",
                              "secret": "<64 hex>", "created": 1700000000.0}, ...]}

A key is used by exactly one sender (``sender``, a node name of role ``gcs`` or ``drone``) for the
keys under one drone's namespace (``scope``: ``uav1`` covers ``uav1/...``). A GCS holds one key per
drone it commands (it seals its setpoints and commands with it) and each of those drones' own keys
(it opens their telemetry); a drone holds its own key and the keys of the GCSs that command it.
A sample opens only under a key of its namespace whose sender is not the receiving node, so one
drone never holds, and never accepts, another's key. Keys are symmetric: a drone could seal with
the pair key of its GCS, but only that drone accepts that key, so it can forge only to itself.

A fleet key (role and sender ``fleet``) covers the fleet's own bookkeeping topics outside any
drone's namespace (``zr_link``: the loss-feedback probes every node sends and hears): every node holds
it and seals with it, so it proves membership of the fleet, not which member sent a probe.

Rotation: a keyring holds several keys per (sender, scope); the newest (``created``) seals, every
one opens until it is removed from the file. Revocation: ``<dir>/revoked.json`` (a list of key
ids) is re-read with the keyring, at most ``refresh_s`` after it changes (or at once on
:meth:`Keyring.reload`, which the apps call on SIGHUP). Secrets are never logged or put in a repr.

Threading: lookups and reloads take one lock; a reload swaps whole tables.
"""
from __future__ import annotations

import json
import os
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

REVOKED_FILE = "revoked.json"
KEY_ID = re.compile(r"^[0-9a-f]{8}$")     # 4 bytes on the wire
FLEET = "fleet"     # the role and sender of a key every node of the fleet holds (see the module doc)
ROLES = ("gcs", "drone", FLEET)
DEFAULT_REFRESH_S = 2.0


class KeyringError(ValueError):
    """A keyring file that is missing, unreadable by its owner only, or malformed."""


@dataclass(frozen=True, slots=True)
class LinkKey:
    """One link key. ``secret`` is excluded from the repr: a key must never reach a log."""
    key_id: str
    sender: str
    role: str           # the sender's role: "gcs" (claims checked against it), "drone", or "fleet" (shared)
    scope: str          # the drone namespace whose keys it seals
    secret: bytes = field(repr=False)
    created: float = 0.0

    @property
    def wire_id(self) -> bytes:
        return bytes.fromhex(self.key_id)


def parse_key(entry: dict[str, object]) -> LinkKey:
    try:
        key_id, secret = str(entry["id"]), bytes.fromhex(str(entry["secret"]))
        key = LinkKey(key_id, str(entry["sender"]), str(entry["role"]), str(entry["scope"]), secret,
                      float(entry.get("created", 0.0)))  # type: ignore[arg-type]
    except (KeyError, TypeError, ValueError) as exc:
        raise KeyringError(f"malformed link key entry: {type(exc).__name__}") from None  # never echo the secret
    if not KEY_ID.match(key.key_id) or len(key.secret) != 32 or key.role not in ROLES \
            or (key.role == FLEET) != (key.sender == FLEET):
        raise KeyringError(f"link key {key.key_id[:16]!r}: id is 8 hex digits, secret 32 bytes, role gcs|drone|fleet "
                           "(sender fleet exactly for role fleet)")
    return key


class Keyring:
    """The link keys of one node (``node``), loaded from ``<dir>/<node>.json`` (see the module doc)."""

    def __init__(self, directory: str | os.PathLike[str], node: str, refresh_s: float = DEFAULT_REFRESH_S) -> None:
        self.directory = Path(directory)
        self.node = node
        self.path = self.directory / f"{node}.json"
        self.refresh_s = refresh_s
        self._lock = threading.Lock()
        self._stamp: tuple[float, float] = (-1.0, -1.0)
        self._checked = 0.0
        self._by_id: dict[bytes, LinkKey] = {}
        self._revoked: frozenset[bytes] = frozenset()
        self.reloads = 0        # bumped by every reload: users cache lookups per generation
        self.reload()

    # -- loading ------------------------------------------------------------------------------
    def _mtimes(self) -> tuple[float, float]:
        revoked = self.directory / REVOKED_FILE
        return (self.path.stat().st_mtime, revoked.stat().st_mtime if revoked.exists() else 0.0)

    def reload(self) -> None:
        """Read the keyring and the revocation list again (SIGHUP; also every ``refresh_s`` on use)."""
        try:
            stamp = self._mtimes()
            mode = self.path.stat().st_mode & 0o777
            data = json.loads(self.path.read_text())
        except (OSError, ValueError) as exc:
            raise KeyringError(f"link keyring {self.path}: {exc}") from None
        if mode & 0o077:
            raise KeyringError(f"link keyring {self.path} is mode {oct(mode)}: it must be 0600")
        if not isinstance(data, dict) or data.get("node") != self.node or not isinstance(data.get("keys"), list):
            raise KeyringError(f"link keyring {self.path} is not {self.node!r}'s keyring")
        keys = [parse_key(e) for e in data["keys"]]
        revoked_path = self.directory / REVOKED_FILE
        revoked: list[str] = []
        if revoked_path.exists():
            try:
                revoked = [str(r) for r in json.loads(revoked_path.read_text())]
            except (OSError, ValueError, TypeError) as exc:
                raise KeyringError(f"revocation list {revoked_path}: {exc}") from None
        with self._lock:
            self._by_id = {k.wire_id: k for k in keys}
            self._revoked = frozenset(bytes.fromhex(r) for r in revoked if KEY_ID.match(r))
            self._stamp = stamp
            self._checked = time.monotonic()
            self.reloads += 1

    def refresh(self) -> None:
        """Reload if ``refresh_s`` passed and a file changed: the bound on a revocation taking effect."""
        now = time.monotonic()
        if now - self._checked < self.refresh_s:
            return
        self._checked = now
        try:
            changed = self._mtimes() != self._stamp
        except OSError:
            return      # keep the keys in force while a file is being replaced
        if changed:
            try:
                self.reload()
            except KeyringError:
                pass    # a half-written file: the next refresh reads the finished one

    # -- lookups ------------------------------------------------------------------------------
    def sealing_key(self, scope: str) -> LinkKey | None:
        """The key this node seals ``scope``'s samples with: its newest unrevoked one (else the fleet's
        for that scope), or None."""
        self.refresh()
        with self._lock:
            live = [k for k in self._by_id.values() if k.scope == scope and k.wire_id not in self._revoked]
            mine = [k for k in live if k.sender == self.node] or [k for k in live if k.role == FLEET]
        return max(mine, key=lambda k: k.created) if mine else None

    def opening_key(self, wire_id: bytes) -> tuple[LinkKey | None, bool]:
        """(the key of ``wire_id`` or None, whether it is revoked)."""
        self.refresh()
        with self._lock:
            return self._by_id.get(wire_id), wire_id in self._revoked

    def key_ids(self) -> list[str]:
        with self._lock:
            return sorted(k.key_id for k in self._by_id.values())

    def __repr__(self) -> str:
        return f"Keyring({self.node!r}, {len(self._by_id)} keys, {len(self._revoked)} revoked)"
