"""``zenoh-robot router``: a Zenoh router with the project's session config, secure and domain options.

Zenoh's Python API opens a session in router mode, so no ``zenohd`` is needed: it routes for
clients and peers, and under ``--secure`` it is where the role ACL is enforced for every client
(docs/security.md). It prints one status line when the set of connected nodes changes (and
every ``--status`` seconds), and closes cleanly on Ctrl-C or SIGTERM.
"""
from __future__ import annotations

import argparse
import signal
import threading
import time
from typing import TYPE_CHECKING, Any

from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.session_config import SessionConfig

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
DEFAULT_SECURE_LISTEN = "tls/0.0.0.0:7447"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("router", help="run a Zenoh router (the secure system's ACL enforcer)")
    p.add_argument("--listen", "-l", action="append", default=[], metavar="ENDPOINT",
                   help=f"listen endpoint, repeatable (default {DEFAULT_LISTEN}, or {DEFAULT_SECURE_LISTEN} "
                        "with --secure)")
    p.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT",
                   help="another router to link to, repeatable")
    p.add_argument("--secure", metavar="DIR", help="keys directory from `zenoh-robot keys` (TLS/QUIC, mTLS, ACL)")
    p.add_argument("--cert-name", default="router", help="this router's certificate in DIR (default router)")
    p.add_argument("--domain", default=None, metavar="N", help="domain id (env ZR_DOMAIN): the ACL's key prefix")
    p.add_argument("--no-scouting", action="store_true", help="do not answer multicast scouting")
    p.add_argument("--status", type=float, default=10.0, metavar="S", help="status line every S seconds (0: on change)")
    p.add_argument("--duration", type=float, metavar="S", help="exit after S seconds")
    p.add_argument("--lossy", action="store_true",
                   help="tune for lossy links (batches under the MTU, keep-alive every 100 ms, 10 s lease, "
                        "250 ms handshake tries): the ground router of a swarm on a radio link")
    p.set_defaults(func=run)


def router_config(args: argparse.Namespace) -> SessionConfig:
    from zenoh_robot.session_config import LOSSY_LINK, SessionConfig, SessionConfigError, resolve_domain

    listen = args.listen or [DEFAULT_SECURE_LISTEN if args.secure else DEFAULT_LISTEN]
    try:
        domain = resolve_domain(args.domain)
        if args.secure:
            # The router uses no keys of its own; its domain only scopes the ACL it enforces.
            return SessionConfig(mode="router", listen=listen, connect=args.connect, secure=args.secure,
                                 name=args.cert_name, domain=domain, multicast_scouting=not args.no_scouting)
        # The apps' own lossy-link settings (session_config.LOSSY_LINK), not a copy of them.
        lossy: dict[str, Any] = dict(LOSSY_LINK, accept_timeout_s=1.0) if getattr(args, "lossy", False) else {}
        return SessionConfig(mode="router", listen=listen, connect=args.connect, domain=domain,
                             multicast_scouting=not args.no_scouting, shared_memory=False, **lossy)
    except SessionConfigError as exc:
        raise CliError(str(exc)) from None


def connected(session: Any) -> list[str]:
    """One entry per connected node: kind, zid, certificate name (secure) and remote address."""
    kinds = {str(t.zid): str(t.whatami) for t in session.info.transports()}
    out = {}
    for link in session.info.links():
        zid = str(link.zid)
        who = f" {link.auth_identifier}" if getattr(link, "auth_identifier", None) else ""
        out[zid] = f"{kinds.get(zid, '?')} {zid[:8]}{who} {link.dst}"
    for zid, kind in kinds.items():
        out.setdefault(zid, f"{kind} {zid[:8]}")
    return sorted(out.values())


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.session_config import SessionConfigError, open_session

    config = router_config(args)
    try:
        session = open_session(config)
    except SessionConfigError as exc:
        raise CliError(str(exc)) from None
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    deadline = None if args.duration is None else time.monotonic() + args.duration
    what = f"secure ({config.name}, {args.secure})" if config.secure else "plain"
    print(f"router {session.info.zid()} {what}, domain {config.domain}, listening on {', '.join(config.listen)}",
          flush=True)
    last: list[str] | None = None
    last_print = 0.0
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            now = connected(session)
            if now != last or (args.status > 0 and time.monotonic() - last_print >= args.status):
                print(f"router: {len(now)} connected" + "".join(f" | {x}" for x in now), flush=True)
                last, last_print = now, time.monotonic()
            stop.wait(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        session.close()
    print("router: closed", flush=True)
    return 0
