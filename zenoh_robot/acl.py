"""Roles of a secure system and the Zenoh access control they imply (no cryptography here).

``roles.yaml`` in a keys directory (written by ``zenoh-robot keys``) says which node name is a
gcs, a drone or a router and which drones a GCS commands; :func:`acl_config` turns it into Zenoh's
``access_control`` config, deny by default, with subjects matched by certificate common name.
The library needs this (a secure :class:`~zenoh_robot.session_config.SessionConfig` builds its
ACL when it opens) without the tools' ``cryptography`` dependency, hence its own module.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

ROLES = ("gcs", "drone", "router")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,62}$")   # a node name is also a key chunk and a file name


class KeysError(ValueError):
    """A keys directory or request that cannot work; the message says what to do."""


def check_name(name: str, what: str = "node name") -> str:
    """``name`` if it is a valid node name (a key chunk and a file name), else :class:`KeysError`."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise KeysError(f"invalid {what} {name!r}: letters, digits, underscores, not starting with a digit")
    return name


@dataclass
class NodeEntry:
    name: str
    role: str
    drones: list[str] = field(default_factory=list)   # for a GCS: the drones it may command


def load_roles(keys_dir: str | Path) -> dict[str, NodeEntry]:
    """``roles.yaml`` as entries; malformed entries are an error, never skipped (an ACL hole)."""
    path = Path(keys_dir) / "roles.yaml"
    if not path.is_file():
        return {}
    data = yaml.safe_load(path.read_text()) or {}
    nodes = data.get("nodes") or {}
    if not isinstance(nodes, dict):
        raise KeysError(f"{path}: 'nodes' must be a mapping")
    out: dict[str, NodeEntry] = {}
    for name, entry in nodes.items():
        if not isinstance(entry, dict) or entry.get("role") not in ROLES:
            raise KeysError(f"{path}: node {name!r} needs role: one of {', '.join(ROLES)}")
        drones = entry.get("drones") or []
        if not isinstance(drones, list):
            raise KeysError(f"{path}: node {name!r}: drones must be a list")
        out[check_name(str(name))] = NodeEntry(str(name), entry["role"], [check_name(str(x)) for x in drones])
    return out


def save_roles(d: Path, nodes: dict[str, NodeEntry]) -> None:
    data = {"nodes": {n.name: ({"role": n.role, "drones": n.drones} if n.drones else {"role": n.role})
                      for n in sorted(nodes.values(), key=lambda n: n.name)}}
    # Written aside and renamed: a session opening meanwhile reads the old file or the new, never half.
    tmp = d / f".roles.yaml.{os.getpid()}"
    tmp.write_text("# Who is what; the ACL of every secure session is generated from this.\n"
                   + yaml.safe_dump(data, sort_keys=False))
    os.replace(tmp, d / "roles.yaml")



# --- access control ---------------------------------------------------------------------------

_ALL = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
        "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
_GRAPH_READ = ["declare_liveliness_subscriber", "liveliness_query"]
# Key families the library and apps use besides topics (each one's writer is restricted below).
_GRAPH = "@zr/lv"            # graph tokens: @zr/lv/<kind>/<zid>/<gid>/<namespace>/<node>/...
_CLAIM = "@zr/claim/*"       # node name claims: @zr/claim/<scope>/<namespace>/<node>/<zid>/<since>/<state>
_ALIVE = "@zr/alive"         # MANUAL_BY_TOPIC / leased publishers' heartbeats: @zr/alive/<topic key>
_CONTROL = "zr_gcs"          # a GCS's liveliness token zr_gcs/<client id> (drone_contract.messages)
_LINK = "zr_link"            # loss-feedback probes every node sends and hears (loss_feedback.LINK_TOPIC)
# Nodes a GCS runs in the root namespace (gcs app, `gcs cmd`): their parameter services live at
# @srv/<node>/... whatever the certificate's name.
_GCS_NODES = ("gcs", "gcs_cmd")


def domain_prefix(domain: int) -> str:
    """The key prefix of a domain: '' for 0 (today's keys), ``zr<N>/`` otherwise."""
    return f"zr{domain}/" if domain else ""


def acl_config(nodes: dict[str, NodeEntry], domain: int = 0) -> dict[str, Any]:
    """Zenoh ``access_control`` for the roles in ``nodes``: everything not allowed here is denied.

    Enforced by each session on its own links, by the certificate CN of the node at the other
    end (so a router enforces it for its clients; a client trusts the router it authenticated).
    Each rule below says why it exists; tests/wing/test_secure_apps.py runs the real companion and
    GCS through a router with these rules and fails on any message the router drops for them.
    Keys beginning with ``@`` are verbatim in Zenoh: ``**`` never matches ``@srv/...`` or
    ``@zr/...``, so those families are granted by name. Egress to any known node is allowed:
    what reaches a node was admitted on its way in.
    """
    p = domain_prefix(domain)
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []

    def rule(rid: str, messages: list[str], keys: list[str], flows: list[str] | None = None,
             permission: str = "allow") -> str:
        rules.append({"id": rid, "messages": messages, "flows": flows or ["ingress"], "permission": permission,
                      "key_exprs": keys})
        return rid

    # '**' never matches a verbatim '@' chunk: the put-carried service keys are named (services/keys.py).
    everything = [f"{p}**", f"{p}@srv/**", f"{p}@srv/**/@rq", f"{p}@srv/**/@rp/*", f"{p}@zr/**"]
    egress = rule("egress_all", _ALL, everything, ["egress"])
    # Every node keeps the graph (node list, matching, QoS checks, duplicate-name refusal).
    graph_read = rule("graph_read", _GRAPH_READ, [f"{p}{_GRAPH}/**", f"{p}{_CLAIM}/**"])
    # Loss feedback: every node probes the link and reports the loss it hears, so every node
    # sends and hears probes. A node with a valid certificate can report false loss; the worst
    # it gets is its peers' copies raised to the repeat plan's bound (docs/security.md).
    link_probe = rule("link_probe", ["put", "declare_subscriber"], [f"{p}{_LINK}/*"])
    router_all = rule("router_all", _ALL, everything + [f"{p}{_CONTROL}/**"])
    for node in sorted(nodes.values(), key=lambda n: n.name):
        subjects.append({"id": f"cn_{node.name}", "cert_common_names": [node.name]})
        if node.role == "router":
            own = [router_all, egress]
        elif node.role == "drone":
            own = [egress, graph_read, link_probe, *_drone_rules(rule, p, node.name)]
        else:
            own = [egress, graph_read, link_probe, *_gcs_rules(rule, p, node)]
        policies.append({"id": f"policy_{node.name}", "rules": own, "subjects": [f"cn_{node.name}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def _drone_rules(rule: Any, p: str, name: str) -> list[str]:
    ns = f"{p}{name}"
    return [
        # Its telemetry, images, events, statistics, MAVLink tunnel: all under its own namespace,
        # so a drone can neither spoof another's state nor read another's (unless a GCS relays it).
        rule(f"drone_{name}_data", ["put", "delete", "declare_subscriber"], [f"{ns}/**"]),
        # Its command and parameter services (@srv/<id>/command, @srv/<id>/companion/...).
        rule(f"drone_{name}_srv", ["declare_queryable", "reply"], [f"{p}@srv/{name}/**"]),
        # The same services' put-carried calls (services.py: requests on <key>/@rq, replies on
        # <key>/@rp/<client>): '**' never matches a verbatim '@' chunk, so they are named.
        rule(f"drone_{name}_srv_requests", ["declare_subscriber"], [f"{p}@srv/{name}/**/@rq"]),
        rule(f"drone_{name}_srv_replies", ["put"], [f"{p}@srv/{name}/**/@rp/*"]),
        # Graph tokens only for nodes in its own namespace.
        rule(f"drone_{name}_graph", ["liveliness_token"], [f"{p}{_GRAPH}/*/*/*/{name}/**", f"{p}{_CLAIM}/{name}/**"]),
        # Heartbeats of its own publishers, and the GCS's heartbeats on its setpoint subscription.
        rule(f"drone_{name}_alive", ["put", "declare_subscriber"], [f"{p}{_ALIVE}/{name}/**"]),
        # The companion watches which GCSs are alive (control passes on when the holder's token goes).
        rule(f"drone_{name}_control_watch", _GRAPH_READ, [f"{p}{_CONTROL}/**"]),
        # Its own setpoints (and their liveliness) come from a GCS only: a compromised drone must not
        # steer itself or keep a dead GCS's stream looking alive. Zenoh: deny beats allow.
        rule(f"drone_{name}_no_setpoint", ["put", "delete"], [f"{ns}/setpoint", f"{p}{_ALIVE}/{name}/setpoint",
                                                             f"{ns}/presence", f"{p}{_ALIVE}/{name}/presence"],
             permission="deny"),
    ]


def _gcs_rules(rule: Any, p: str, node: NodeEntry) -> list[str]:
    name = node.name
    own_srv = [f"{p}@srv/{name}/**", *(f"{p}@srv/{n}/**" for n in _GCS_NODES)]
    out = [
        # An operator's station sees everything: telemetry of every drone, statistics, heartbeats.
        rule(f"gcs_{name}_read", ["declare_subscriber"], [f"{p}**", f"{p}{_ALIVE}/**"]),
        # Its own topics and services; its root-namespace nodes' parameter services.
        rule(f"gcs_{name}_own", ["put", "delete", "declare_queryable", "reply", "query"],
             [f"{p}{name}/**", *own_srv]),
        # Put-carried service calls (services/multicast.py): its own services' requests and replies, and the
        # replies addressed to its clients ('**' never matches the verbatim '@rq'/'@rp' chunks).
        rule(f"gcs_{name}_srv_requests", ["declare_subscriber"], [f"{k}/@rq" for k in own_srv]),
        rule(f"gcs_{name}_srv_replies", ["put"], [f"{k}/@rp/*" for k in own_srv]),
        rule(f"gcs_{name}_srv_answers", ["declare_subscriber"], [f"{p}@srv/**/@rp/*"]),
        # Statistics of its root-namespace nodes' other subscriptions (statistics/zr_link, ...).
        rule(f"gcs_{name}_root_statistics", ["put"], [f"{p}statistics/**"]),
        # Graph tokens of its nodes: root namespace (gcs, gcs_cmd) or its own.
        rule(f"gcs_{name}_graph", ["liveliness_token"], [f"{p}{_GRAPH}/*/*/*/%/**", f"{p}{_GRAPH}/*/*/*/{name}/**",
                                                         f"{p}{_CLAIM}/%/**", f"{p}{_CLAIM}/{name}/**"]),
        # The liveliness token by which drones know it is alive (zr_gcs/<client id>), and the others'.
        # The client id is free text: any authorised GCS may use any id (docs/security.md, limits).
        rule(f"gcs_{name}_control", ["liveliness_token", *_GRAPH_READ], [f"{p}{_CONTROL}/*", f"{p}{_CONTROL}/**"]),
    ]
    if node.drones:
        keys = []
        for d in node.drones:
            keys += [f"{p}{d}/setpoint",            # the setpoint stream
                     f"{p}{_ALIVE}/{d}/setpoint",   # its heartbeats (leased / manual liveliness)
                     f"{p}{d}/presence",            # the GCS in control is still running (renews its lease)
                     f"{p}{_ALIVE}/{d}/presence",
                     f"{p}{d}/statistics/**",       # its subscriptions' statistics, filed under the drone
                     f"{p}{d}/mavlink/up",          # QGC's MAVLink through the tunnel (companion decides)
                     f"{p}@srv/{d}/**",             # commands and the companion's parameter services
                     f"{p}@srv/{d}/**/@rq"]         # ... and their put-carried requests
        out.append(rule(f"gcs_{name}_command", ["put", "query"], keys))
    return out
