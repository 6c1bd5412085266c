"""Zenoh session configuration: our defaults, validated endpoints, JSON5 files.

Defaults follow the verified Zenoh 1.10 facts in docs/architecture.md: ``max_links`` 2 so a peer can
hold a TCP link (reliable samples) *and* a UDP link (best-effort samples) where it is given a
``udp/`` endpoint; shared memory only when every endpoint is loopback, because across hosts or
namespaces it would silently bypass the network under test.

UDP only where asked for (docs/architecture.md, "UDP only where asked for"): a session given no
``udp/`` endpoint listens on TCP and never dials a scouted peer's UDP locator. Zenoh sends reliable
messages (declarations included) on *any* link when no reliable one exists yet (its link selection's
"any match"), and a transport a peer opened through our UDP locator carried its first declarations
over UDP: a datagram the host dropped (receive buffer full) lost a subscriber or token declaration for
the transport's lifetime ("Unknown wire expr" in Zenoh's log; a stream or node never seen).

Two options keep systems apart (docs/security.md):
- ``domain`` (or env ``ZR_DOMAIN``), like ROS_DOMAIN_ID: domain N > 0 sets Zenoh's session
  ``namespace`` to ``zr<N>``, so every key this session uses (topics, ``@srv`` services, ``@zr``
  graph tokens) is prefixed on the wire, in one place, and systems in other domains neither see
  nor reach it. Domain 0 keeps the historic keys.
- ``secure`` (a keys directory made by ``zenoh-robot keys``) with ``name``: TLS/QUIC only, mutual
  authentication against the directory's CA, this node's certificate, and an access-control
  list generated from the directory's ``roles.yaml`` (:mod:`zenoh_robot.acl`), deny by default.
"""
from __future__ import annotations

import ipaddress
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from zenoh_robot import acl

MODES = ("peer", "client", "router")
PROTOCOLS = ("tcp", "udp", "quic", "tls", "ws", "unixsock-stream", "serial", "unixpipe", "vsock")
SECURE_PROTOCOLS = ("tls", "quic")
# Zenoh's whitelist of link protocols (opened and accepted); without UDP for a session not asked for UDP.
LINK_PROTOCOLS = "transport/link/protocols"
MAX_DOMAIN = 232            # ROS_DOMAIN_ID's range: one number means the same thing to both worlds
# The resilient transport's group. Not 224.0.0.251 (mDNS: every printer and phone on the LAN
# answers there) and not in 224.0.0.0/24 at all (IANA-assigned link-local protocols): 239.255/16
# is the IPv4 organisation-local scope (RFC 2365), which routers at a site border never forward.
RESILIENT_GROUP = "239.255.74.71:7460"
# What a unicast or routed session across a lossy radio link needs (the lossy-link experiment found it,
# docs/lossy-link.md): batches under the MTU (one lost fragment loses no batch), a 10 s lease held by
# keep-alives every 100 ms through fades, and ``lossy`` (fast open, UDP dialled first, a reliable link
# never re-dialled in a hurry: see :func:`slow_redial`). One place for the apps' resilient profile and
# ``zenoh-robot router --lossy``: ``SessionConfig(**LOSSY_LINK, ...)``.
LOSSY_LINK: dict[str, Any] = {"batch_size": 1300, "lease_s": 10.0, "keep_alive": 100, "lossy": True}
# Per-endpoint connect retry of a reliable (TCP, TLS, QUIC, WS) link in a lossy session: tried at start-up,
# then after 5 s, doubling to once a minute (Zenoh's per-endpoint ``retry_period_*`` keys).
SLOW_REDIAL: dict[str, float] = {"retry_period_init_ms": 5000, "retry_period_max_ms": 60000,
                                 "retry_period_increase_factor": 2}


def fast_open(open_timeout_ms: int = 250, retry_init_ms: int = 50, retry_max_ms: int = 200,
              client: bool = False) -> dict[str, Any]:
    """Zenoh keys for a unicast session that must form across a lossy link (``SessionConfig(extra=...)``).

    A unicast open is 4 messages (InitSyn/InitAck/OpenSyn/OpenAck); over UDP each is one datagram
    that Zenoh never re-sends within a try, so a try succeeds with p = (1 - loss)^4 and a lost
    message costs a whole open timeout. Zenoh 1.10's defaults (10 s open timeout, retries backing
    off 1 -> 4 s) turn 50 % loss into minutes; short tries retried at once make it seconds
    (docs/results/transports.md). A client also needs ``connect/timeout_ms: -1`` and
    ``exit_on_failure: false``: Zenoh's client defaults (0, true) make ``open`` fail at the first
    lost datagram instead of retrying.
    """
    keys: dict[str, Any] = {
        "transport/unicast/open_timeout": open_timeout_ms,
        "transport/unicast/accept_timeout": max(open_timeout_ms, 1000),
        "connect/retry": {"period_init_ms": retry_init_ms, "period_max_ms": retry_max_ms,
                          "period_increase_factor": 1.5},
    }
    if client:
        keys["connect/timeout_ms"] = -1
        keys["connect/exit_on_failure"] = False
    return keys


def udp_first(endpoints: list[str]) -> list[str]:
    """``endpoints`` with the UDP ones first, each group in its given order."""
    return sorted(endpoints, key=lambda e: not e.startswith("udp/"))


def slow_redial(endpoint: str) -> str:
    """``endpoint`` with :data:`SLOW_REDIAL` in its config part if it dials a reliable (stream) link.

    Across 50-70 % loss a TCP link stalls on its own backed-off retransmissions until the 10 s lease
    expires (10-25 s into the loss); the session lives on over its UDP link. A peer then re-dials the
    TCP endpoint at once and every 50-200 ms (``fast_open``'s retry), 41-91 tries in 40-60 s, some half
    done across the loss; around the half-accepted ones both processes' Zenoh runtimes froze for 6.4 s
    (UDP link included) or the session ended, in 5 of 6 runs (docs/lossy-link.md, unicast). A client never re-dials a
    lost link (Zenoh keeps its session on the links left), which is why the router cells flew. Dialled
    at start-up, then slowly: the UDP link carries everything once TCP is gone, as a client's does.
    Zenoh 1.10 re-dials a lost link only when its endpoint equals the configured one, config part
    included, so an endpoint written with these keys is not re-dialled on link loss at all (a whole
    session lost is re-dialled as before); a Zenoh that compared locators would re-dial on this period.
    Keys the endpoint already sets win; UDP and local endpoints are returned unchanged. The keys come
    out sorted, as Zenoh writes an endpoint back.
    """
    if endpoint.split("/", 1)[0] not in ("tcp", "tls", "quic", "ws"):
        return endpoint
    head, _, cfg = endpoint.partition("#")
    keys = {k: f"{v:g}" for k, v in SLOW_REDIAL.items()}
    keys.update(kv.partition("=")[::2] for kv in cfg.split(";") if kv)
    return head + "#" + ";".join(f"{k}={v}" if v else k for k, v in sorted(keys.items()))


_ENDPOINT = re.compile(r"^(?P<proto>[a-z-]+)/(?P<addr>[^?#]+)(?:\?(?P<meta>[^#]*))?(?:#(?P<cfg>.*))?$")


class SessionConfigError(ValueError):
    """A session configuration that cannot work; the message names the bad part."""


# Zenoh's errors arrive as Rust's Debug text: the source file and line of the Rust code that raised them
# (" at /root/.cargo/.../lib.rs:1484."), serde's Message { msg: ..., location: ... } wrapping, and for a
# JSON5 syntax error pest's multi-line caret picture, whose "expected boolean or null" points wherever the
# parser gave up, not at the missing "}". zenoh_problem() turns that into one line a user can act on.
_RUST_SOURCE = re.compile(r"\s+at\s+/\S+?\.rs:\d+\.?")
_SERDE = re.compile(r'msg: "(?P<msg>(?:[^"\\]|\\.)*)", location: '
                    r'(?:Some\(Location \{ line: (?P<line>\d+), column: (?P<col>\d+) \}\)|None)')
_PEST = re.compile(r"-->\s*(?P<line>\d+):(?P<col>\d+).*?=\s*(?P<expected>[^\n]+)", re.S)
_PAIRS = {"{": "}", "[": "]"}


def zenoh_problem(exc: BaseException, text: str | None = None) -> str:
    """One line for a Zenoh config error, with no Rust source paths; ``text``: the JSON5 it came from,
    to name an unbalanced bracket where the parser's own position would mislead."""
    raw = _RUST_SOURCE.sub("", str(exc))
    m = _SERDE.search(raw)
    if m:
        msg = re.sub(r"\\(.)", lambda e: "\n" if e[1] == "n" else e[1], m["msg"])   # Rust's Debug escapes
        if _PEST.search(msg):
            return _syntax_problem(msg, text)
        # Without ``text`` the location is inside a value handed over in code, not in a file a user wrote.
        where = f"line {m['line']}, column {m['col']}: " if m["line"] and text is not None else ""
        return where + msg
    if _PEST.search(raw):
        return _syntax_problem(raw, text)
    unreached = re.search(r"Unable to connect to any of \[(.*?)\]", raw)
    if unreached:   # a client whose router is not there
        endpoints = re.findall(r"Single\(([^)]*)\)", unreached[1]) or [unreached[1]]
        return f"cannot reach {', '.join(endpoints)} (is a router running there?)"
    unknown = re.fullmatch(r'\s*Str\("(.*)"\)\s*', raw)
    if unknown:
        return unknown[1]
    return " ".join(raw.split())


def _syntax_problem(pest: str, text: str | None) -> str:
    unbalanced = _bracket_problem(text) if text is not None else None
    if unbalanced:
        return unbalanced
    m = _PEST.search(pest)
    assert m is not None
    expected = m["expected"].strip().removeprefix("expected ")
    if expected in ("null", "boolean or null"):    # pest's guess at a bare word: a value it cannot read
        expected = "a value: a quoted string, a number, true, false, null, {...} or [...]"
    return f"JSON5 syntax error at line {m['line']}, column {m['col']}: expected {expected}"


def _bracket_problem(text: str) -> str | None:
    """The first unbalanced ``{}``/``[]`` of JSON5 ``text`` (strings and comments skipped), or None."""
    def at(i: int) -> str:
        return f"line {text.count(chr(10), 0, i) + 1}, column {i - text.rfind(chr(10), 0, i)}"

    stack: list[tuple[str, int]] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in "\"'":
            i += 1
            while i < n and text[i] != c:
                i += 2 if text[i] == "\\" else 1
        elif text.startswith("//", i):
            i = text.find("\n", i)
            i = n if i < 0 else i
        elif text.startswith("/*", i):
            i = text.find("*/", i + 2)
            i = n if i < 0 else i + 1
        elif c in _PAIRS:
            stack.append((c, i))
        elif c in "}]":
            if not stack:
                return f"{at(i)}: {c!r} closes nothing (one too many)"
            opener, where = stack.pop()
            if _PAIRS[opener] != c:
                return f"{at(i)}: {c!r} where {_PAIRS[opener]!r} was expected (to close the {opener!r} of {at(where)})"
        i += 1
    if stack:
        opener, where = stack[-1]
        return f"the {opener!r} of {at(where)} is never closed (a {_PAIRS[opener]!r} is missing)"
    return None


def validate_endpoint(endpoint: str) -> str:
    m = _ENDPOINT.match(endpoint.strip()) if isinstance(endpoint, str) else None
    if not m:
        raise SessionConfigError(f"invalid endpoint {endpoint!r}: expected PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447")
    proto, addr = m["proto"], m["addr"]
    if proto not in PROTOCOLS:
        raise SessionConfigError(f"invalid endpoint {endpoint!r}: unknown protocol {proto!r} ({', '.join(PROTOCOLS)})")
    if proto in ("tcp", "udp", "quic", "tls", "ws"):
        host, sep, port = addr.rpartition(":")
        if not sep or not host:
            raise SessionConfigError(f"invalid endpoint {endpoint!r}: missing ':PORT'")
        if not port.isdigit() or not 0 <= int(port) <= 65535:
            raise SessionConfigError(f"invalid endpoint {endpoint!r}: port {port!r} is not 0-65535")
    return endpoint.strip()


def _is_multicast(endpoint: str) -> bool:
    m = _ENDPOINT.match(endpoint)
    if not m or m["proto"] != "udp":
        return False
    try:
        return ipaddress.ip_address(m["addr"].rpartition(":")[0].strip("[]")).is_multicast
    except ValueError:
        return False


# Sessions opened on a multicast transport, by zid (a zenoh Session takes no weak reference and
# exposes no config); bounded, oldest forgotten first: long-closed sessions need no entry.
_MULTICAST_ZIDS: dict[str, None] = {}
_MAX_TRACKED = 1024


def is_multicast_session(session: zenoh.Session) -> bool:
    """True if ``session`` was opened by :func:`open_session` on a UDP multicast transport."""
    try:
        return str(session.zid()) in _MULTICAST_ZIDS
    except Exception:     # a closed session: nothing more will be declared on it anyway
        return False


def _is_loopback(endpoint: str) -> bool:
    m = _ENDPOINT.match(endpoint)
    if not m:
        return False
    if m["proto"] in ("unixsock-stream", "unixpipe"):
        return True
    host = m["addr"].rpartition(":")[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class SessionConfig:
    mode: str = "peer"
    listen: list[str] = field(default_factory=lambda: ["tcp/0.0.0.0:0"])
    connect: list[str] = field(default_factory=list)
    multicast_scouting: bool = True
    shared_memory: bool | None = None      # None: on only if every endpoint is loopback
    max_links: int = 2
    batch_size: int | None = None          # bytes per batch; under the path MTU avoids IP fragments
    lease_s: float | None = None           # transport lease; longer survives heavy loss
    keep_alive: int | None = None          # keep-alives per lease
    # Zenoh's default 10 s accept timeout makes close() hang 10 s whenever a UDP handshake
    # with a peer that has just gone is half done; the opener retries anyway.
    accept_timeout_s: float = 2.0
    extra: dict[str, Any] = field(default_factory=dict)   # raw zenoh keys -> JSON values
    source: str | None = None              # JSON5 file this was loaded from, if any
    domain: int | None = None              # None: env ZR_DOMAIN, else 0
    secure: str | None = None              # keys directory: TLS + mTLS + ACL (see the module doc)
    name: str | None = None                # this node's certificate name in ``secure``
    verify_name: bool = True               # check the dialled host against the peer's certificate SAN
    # A unicast session across a lossy link (docs/results/transports.md): fast_open's short handshake
    # tries retried at once (a client's open also waits and retries instead of failing), UDP
    # endpoints dialled before TCP ones (a client holds the first link that opens; a TCP connect
    # under loss waits on the kernel's SYN back-off), and a lost TCP link never re-dialled in a
    # hurry (slow_redial). Keys in ``extra`` still win.
    lossy: bool = False

    def __post_init__(self) -> None:
        self.domain = resolve_domain(self.domain)
        if self.secure is not None:
            self._init_secure()
        if self.mode not in MODES:
            raise SessionConfigError(f"mode {self.mode!r}: choose one of {', '.join(MODES)}")
        if isinstance(self.listen, str) or isinstance(self.connect, str):
            raise SessionConfigError("listen and connect take lists of endpoints")
        self.listen = [validate_endpoint(e) for e in self.listen]
        self.connect = [validate_endpoint(e) for e in self.connect]
        if self.max_links < 1:
            raise SessionConfigError("max_links must be >= 1")
        if self.batch_size is not None and not 64 <= self.batch_size <= 65535:
            raise SessionConfigError(f"batch_size {self.batch_size}: must be 64..65535 bytes")

    def _init_secure(self) -> None:
        keys = Path(self.secure or "")
        if not self.name:
            raise SessionConfigError("secure session needs the node's certificate name (name=...)")
        for f in ("ca.pem", f"{self.name}.pem", f"{self.name}.key"):
            if not (keys / f).is_file():
                raise SessionConfigError(f"secure: {keys / f} missing (zenoh-robot keys init/issue {self.name})")
        if self.listen == ["tcp/0.0.0.0:0"]:    # the plain default, never meant here
            self.listen = ["tls/0.0.0.0:0"]
        plain = [e for e in self.listen + self.connect if e.split("/", 1)[0] not in SECURE_PROTOCOLS]
        if plain:
            raise SessionConfigError(f"secure session: {plain} not tls/ or quic/ (plain links are refused)")
        try:
            nodes = acl.load_roles(keys)
        except (acl.KeysError, OSError) as exc:
            raise SessionConfigError(f"secure: {exc}") from None
        if self.name not in nodes:
            raise SessionConfigError(f"secure: {self.name!r} has no role in {keys / 'roles.yaml'}")
        # Shared memory would hand payloads to any local process, certificate or not.
        self.shared_memory = False

    @classmethod
    def secured(cls, keys_dir: str | Path, name: str, **kw: Any) -> SessionConfig:
        """A secure session as node ``name`` with the keys in ``keys_dir`` (``SessionConfig(secure=...)``)."""
        return cls(secure=str(keys_dir), name=name, **kw)

    @classmethod
    def localhost(cls, **kw: Any) -> "SessionConfig":
        """Everything on this host: loopback endpoints, scouting on, shared memory allowed."""
        kw.setdefault("listen", ["tcp/127.0.0.1:0"])
        return cls(**kw)

    @classmethod
    def resilient(cls, interface: str, group: str = RESILIENT_GROUP, **kw: Any) -> "SessionConfig":
        """The lossy-link transport of the resilient profile, on network ``interface``.

        Zenoh's UDP multicast transport needs no handshake (peers learn of each other from
        Join messages, here every 250 ms), so a session forms even behind 90 % loss, where a
        unicast handshake almost never completes; keep-alives every 100 ms hold the 10 s lease
        through long bursts; batches stay under the MTU. Everything on it is best effort:
        pair it with ``qos.RESILIENT`` (redundancy + repeats) for streams that must arrive.
        Publishers on such a session never use Zenoh's ``express`` (docs/zenoh-multicast-stall.md:
        express samples in quick succession stall Zenoh 1.10's multicast transport for good).
        """
        kw.setdefault("listen", [f"udp/{group}#iface={interface}"])
        kw.setdefault("multicast_scouting", False)
        kw.setdefault("shared_memory", False)
        kw.setdefault("batch_size", 1300)
        kw.setdefault("lease_s", 10.0)
        kw.setdefault("keep_alive", 100)
        kw.setdefault("extra", {"transport/multicast/join_interval": 250})
        return cls(**kw)

    def uses_udp(self) -> bool:
        """A ``udp/`` endpoint (unicast or multicast) among listen and connect: UDP links are asked for."""
        return any(e.startswith("udp/") for e in self.listen + self.connect)

    def _link_protocols(self) -> dict[str, Any]:
        if self.uses_udp():     # (a whitelist in ``extra`` wins, as every key there does)
            return {}
        return {LINK_PROTOCOLS: [p for p in PROTOCOLS if p != "udp"]}

    def to_json5(self) -> dict[str, Any]:
        """The settings as a nested Zenoh config (for a ``--zenoh`` file or another process)."""
        out: dict[str, Any] = {}
        for key, value in self._values().items():
            node = out
            *parents, leaf = key.split("/")
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = value
        return out

    @property
    def multicast(self) -> bool:
        """True if the session listens on a UDP multicast group (Zenoh's multicast transport)."""
        return any(_is_multicast(e) for e in self.listen)

    @property
    def shared_memory_enabled(self) -> bool:
        if self.shared_memory is not None:
            return self.shared_memory
        endpoints = self.listen + self.connect
        return bool(endpoints) and all(_is_loopback(e) for e in endpoints)

    def to_zenoh(self) -> zenoh.Config:
        if self.source:
            try:
                conf = zenoh.Config.from_file(self.source)
            except Exception as exc:
                raise SessionConfigError(f"{self.source}: {zenoh_problem(exc, _read_text(self.source))}") from None
        else:
            conf = zenoh.Config()
        values = self._values()
        if self.source and conf.get_json(LINK_PROTOCOLS) != "null":
            values.pop(LINK_PROTOCOLS, None)    # the file's own whitelist stands
        for key, value in values.items():
            try:
                conf.insert_json5(key, json.dumps(value))
            except Exception as exc:
                raise SessionConfigError(f"zenoh config {key}={value!r}: {zenoh_problem(exc)}") from None
        return conf

    def _values(self) -> dict[str, Any]:
        values: dict[str, Any] = {
            "mode": self.mode,
            "listen/endpoints": self.listen,
            "connect/endpoints": [slow_redial(e) for e in udp_first(self.connect)] if self.lossy else self.connect,
            "scouting/multicast/enabled": self.multicast_scouting,
            "transport/unicast/max_links": self.max_links,
            **self._link_protocols(),
            "transport/shared_memory/enabled": self.shared_memory_enabled,
            "transport/unicast/accept_timeout": int(self.accept_timeout_s * 1000),
        }
        if self.batch_size is not None:
            values["transport/link/tx/batch_size"] = self.batch_size
        if self.lease_s is not None:
            values["transport/link/tx/lease"] = int(self.lease_s * 1000)
        if self.keep_alive is not None:
            values["transport/link/tx/keep_alive"] = self.keep_alive
        if self.domain:
            values["namespace"] = f"zr{self.domain}"
        if self.secure is not None:
            values.update(self._secure_values())
        if self.lossy:
            values.update(fast_open(client=self.mode == "client"))
        values.update(self.extra)
        return values

    def _secure_values(self) -> dict[str, Any]:
        keys = Path(self.secure or "").resolve()
        cert, key = str(keys / f"{self.name}.pem"), str(keys / f"{self.name}.key")
        tls = "transport/link/tls/"
        return {
            "transport/link/protocols": list(SECURE_PROTOCOLS),
            tls + "root_ca_certificate": str(keys / "ca.pem"),
            tls + "listen_certificate": cert, tls + "listen_private_key": key,
            tls + "connect_certificate": cert, tls + "connect_private_key": key,
            tls + "enable_mtls": True,
            tls + "verify_name_on_connect": self.verify_name,
            "access_control": acl.acl_config(acl.load_roles(keys), self.domain or 0),
        }

    @classmethod
    def from_file(cls, path: str | Path) -> "SessionConfig":
        """Read a Zenoh JSON5 config; its mode/endpoints/scouting fill our fields, the rest is kept."""
        path = Path(path)
        if not path.is_file():
            raise SessionConfigError(f"session config {path} does not exist")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:
            raise SessionConfigError(f"{path}: {zenoh_problem(exc, _read_text(path))}") from None

        def get(key: str, default: Any) -> Any:
            try:
                value = json.loads(conf.get_json(key))
            except Exception:
                return default
            return default if value is None else value

        mode = get("mode", "peer")

        def endpoints(key: str) -> list[str]:
            value = get(key, [])
            # Zenoh allows per-mode endpoint lists: {peer: [...], router: [...]}.
            flat: list[str] = []
            for e in (value.get(mode, []) if isinstance(value, dict) else value):
                # A group ({"strategy": "allOf", "locators": [...]}: a client's several links to one
                # router) is checked locator by locator here and handed to Zenoh as written (extra).
                flat.extend(e["locators"] if isinstance(e, dict) and isinstance(e.get("locators"), list) else [e])
            return flat

        raw_connect = get("connect/endpoints", [])
        groups = [e for e in (raw_connect if isinstance(raw_connect, list) else []) if isinstance(e, dict)]
        text = path.read_text()
        try:
            return cls(
                mode=mode,
                listen=endpoints("listen/endpoints"),
                connect=endpoints("connect/endpoints"),
                multicast_scouting=bool(get("scouting/multicast/enabled", True)),
                # Zenoh fills every key with its default, so "was it in the file" needs the text.
                shared_memory=get("transport/shared_memory/enabled", None) if "shared_memory" in text else None,
                max_links=int(get("transport/unicast/max_links", 2)) if "max_links" in text else 2,
                source=str(path),
                extra={"connect/endpoints": raw_connect} if groups else {},
            )
        except SessionConfigError as exc:   # a bad endpoint or mode: which file it is in
            raise SessionConfigError(f"{path}: {exc}") from None


def _read_text(path: str | Path) -> str | None:
    try:
        return Path(path).read_text(errors="replace")
    except OSError:
        return None


def resolve_domain(domain: int | str | None) -> int:
    """``domain`` or env ``ZR_DOMAIN`` or 0, checked: 0..232."""
    raw: Any = os.environ.get("ZR_DOMAIN", "0") if domain is None else domain
    try:
        value = int(str(raw).strip() or "0")
    except ValueError:
        raise SessionConfigError(f"domain {raw!r}: an integer 0..{MAX_DOMAIN} (ZR_DOMAIN)") from None
    if not 0 <= value <= MAX_DOMAIN:
        raise SessionConfigError(f"domain {value}: must be 0..{MAX_DOMAIN}")
    return value


def open_session(config: SessionConfig | str | Path | None = None) -> zenoh.Session:
    """Open a Zenoh session with our defaults; a bad config is an error here, never a hang."""
    if config is None:
        config = SessionConfig()
    elif not isinstance(config, SessionConfig):
        config = SessionConfig.from_file(config)
    zconf = config.to_zenoh()
    try:
        session = zenoh.open(zconf)
    except Exception as exc:
        raise SessionConfigError(f"cannot open Zenoh session ({config.mode}, listen={config.listen}, "
                                 f"connect={config.connect}): {zenoh_problem(exc)}") from None
    if config.multicast:
        _MULTICAST_ZIDS[str(session.zid())] = None
        while len(_MULTICAST_ZIDS) > _MAX_TRACKED:
            del _MULTICAST_ZIDS[next(iter(_MULTICAST_ZIDS))]
    return session
