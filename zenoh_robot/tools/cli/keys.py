"""``zenoh-robot keys``: the CA and node certificates of a secure system (docs/security.md)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from .main import CliError

DEFAULT_DIR = "keys"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("keys", help="make a CA and node certificates for --secure sessions, link keys for --link-keys")
    ops = p.add_subparsers(dest="keys_action", required=True, metavar="ACTION")
    init = ops.add_parser("init", help="create the CA in DIR (default ./keys)")
    init.add_argument("dir", nargs="?", default=DEFAULT_DIR)
    init.add_argument("--force", action="store_true", help="replace an existing CA (re-issue every node after)")
    issue = ops.add_parser("issue", help="issue NAME's key and certificate, with its role")
    issue.add_argument("name")
    issue.add_argument("--role", required=True, choices=("gcs", "drone", "router"))
    issue.add_argument("--drones", default="", help="for a gcs: the drones it commands, e.g. uav1,uav2")
    issue.add_argument("--san", action="append", default=[], metavar="HOST",
                       help="another host name or address others dial to reach this node; repeatable")
    issue.add_argument("--dir", default=DEFAULT_DIR)
    link = ops.add_parser("link", help="make link keys (sealed samples: --link-keys DIR/link) for a fleet, "
                                       "one keyring per node in DIR/link/<node>.json, 0600")
    link.add_argument("--dir", default=DEFAULT_DIR)
    link.add_argument("--gcs", action="append", default=[], metavar="NAME:DRONE,...",
                      help="a GCS and the drones it commands; repeatable (roles.yaml's are included)")
    link.add_argument("--drone", action="append", default=[], metavar="NAME", help="a drone; repeatable")
    link.add_argument("--rotate", action="store_true",
                      help="add a new key per sender (used from the next load; old ones open until removed)")
    link.add_argument("--revoke", action="append", default=[], metavar="ID|NODE",
                      help="revoke a key id, or every key a node sends with; nodes refuse it within their refresh")
    ls = ops.add_parser("list", help="certificates in DIR: name, role, expiry, key mode")
    ls.add_argument("dir", nargs="?", default=DEFAULT_DIR)
    ls.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        from zenoh_robot.tools import keys
    except ImportError as exc:
        raise CliError(str(exc)) from None
    try:
        if args.keys_action == "init":
            path = keys.init_ca(args.dir, force=args.force)
            print(f"CA {path} (key {Path(args.dir) / 'ca.key'}, 0600: keep it off the vehicles)")
        elif args.keys_action == "issue":
            drones = [d.strip() for d in args.drones.split(",") if d.strip()]
            path = keys.issue(args.dir, args.name, args.role, drones=drones, sans=args.san)
            conf = keys.write_node_config(args.dir, args.name)
            print(f"{args.name} ({args.role}{': ' + ','.join(drones) if drones else ''}): {path}, "
                  f"key {path.with_suffix('.key')} 0600, zenoh config {conf}")
        elif args.keys_action == "link":
            if args.revoke:
                ids = keys.revoke_link_keys(args.dir, args.revoke)
                print(f"revoked link keys {', '.join(ids)} ({Path(args.dir) / keys.LINK_DIR / 'revoked.json'})")
            else:
                gcs = {}
                for spec in args.gcs:
                    name, _, drones = spec.partition(":")
                    gcs[name] = [d.strip() for d in drones.split(",") if d.strip()]
                for path in keys.make_link_keys(args.dir, gcs=gcs, drones=args.drone, rotate=args.rotate):
                    print(f"{path} (0600)")     # paths only: a key never reaches a terminal or a log
        else:
            certs = keys.list_certs(args.dir)
            roles = keys.load_roles(args.dir)
            rows = [{"name": c.name, "role": c.role, "drones": roles[c.name].drones if c.name in roles else [],
                     "expires": c.not_after.date().isoformat(),
                     "key_mode": oct(c.key_mode) if c.key_mode is not None else "missing"} for c in certs]
            if args.json:
                print(json.dumps(rows, indent=2))
            else:
                for r in rows:
                    warn = "" if r["key_mode"] == "0o600" else "  (key not 0600!)"
                    controls = f" -> {','.join(r['drones'])}" if r["drones"] else ""
                    print(f"{r['name']:<16} {r['role']:<7} expires {r['expires']}  key {r['key_mode']}{controls}{warn}")
    except (keys.KeysError, OSError) as exc:
        raise CliError(str(exc)) from None
    return 0
