"""Roles of a secure system and the Zenoh access control they imply (no cryptography here).

``roles.yaml`` in a keys directory (written by ``zenoh-robot keys``) says which node name is a
gcs, a drone or a router and which drones a GCS commands; :func:`acl_config` turns it into Zenoh's
``access_control`` config, deny by default, with subjects matched by certificate common name.
The library needs this (a secure :class:`~zenoh_robot.session_config.SessionConfig` builds its
ACL when it opens) without the tools' ``cryptography`` dependency, hence its own module.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

ROLES = ("gcs", "drone", "router")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,62}$")   # a node name is also a key chunk and a file name


class KeysError(ValueError):
    """A keys directory or request that cannot work; the message says what to do."""


def _check_name(name: str, what: str = "node name") -> str:
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
        out[_check_name(str(name))] = NodeEntry(str(name), entry["role"], [_check_name(str(x)) for x in drones])
    return out


def save_roles(d: Path, nodes: dict[str, NodeEntry]) -> None:
    data = {"nodes": {n.name: ({"role": n.role, "drones": n.drones} if n.drones else {"role": n.role})
                      for n in sorted(nodes.values(), key=lambda n: n.name)}}
    (d / "roles.yaml").write_text("# Who is what; the ACL of every secure session is generated from this.\n"
                                  + yaml.safe_dump(data, sort_keys=False))



# --- access control ---------------------------------------------------------------------------

_ALL = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
        "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
_GRAPH_READ = ["declare_liveliness_subscriber", "liveliness_query"]


def domain_prefix(domain: int) -> str:
    """The key prefix of a domain: '' for 0 (today's keys), ``zr<N>/`` otherwise."""
    return f"zr{domain}/" if domain else ""


def acl_config(nodes: dict[str, NodeEntry], domain: int = 0) -> dict[str, Any]:
    """Zenoh ``access_control`` for the roles in ``nodes``: everything not allowed here is denied.

    Enforced by each session on its own links, by the certificate CN of the node at the other
    end (so a router enforces it for its clients; a client trusts the router it authenticated).
    - gcs: reads anything; puts only on ``<drone>/setpoint`` and ``<drone>/**`` of its drones'
      command topics, and queries their services (``@srv/<drone>/**``: command, parameters).
    - drone ``<id>``: publishes only under ``<id>/``, subscribes under ``<id>/``, serves and replies
      only ``@srv/<id>/**``, and declares graph tokens only for its own namespace.
    - router: everything (it has been authenticated; it relays what its own rules admitted).
    Egress to any known node is allowed: what reaches a node was admitted on its way in.
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

    everything = [f"{p}**", f"{p}@srv/**", f"{p}@zr/**"]
    egress = rule("egress_all", _ALL, everything, ["egress"])
    graph_read = rule("graph_read", _GRAPH_READ, [f"{p}@zr/**"])
    router_all = rule("router_all", _ALL, everything)
    for node in sorted(nodes.values(), key=lambda n: n.name):
        subjects.append({"id": f"cn_{node.name}", "cert_common_names": [node.name]})
        if node.role == "router":
            own = [router_all, egress]
        elif node.role == "drone":
            ns = f"{p}{node.name}"
            own = [egress, graph_read,
                   rule(f"drone_{node.name}_data", ["put", "delete", "declare_subscriber"], [f"{ns}/**"]),
                   rule(f"drone_{node.name}_srv", ["declare_queryable", "reply"], [f"{p}@srv/{node.name}/**"]),
                   rule(f"drone_{node.name}_graph", ["liveliness_token"], [f"{p}@zr/lv/*/*/*/{node.name}/**"]),
                   # Its own setpoints come from a GCS only: a compromised drone must not steer itself
                   # (or a second drone process with its certificate). Zenoh: deny beats allow.
                   rule(f"drone_{node.name}_no_setpoint", ["put", "delete"], [f"{ns}/setpoint"], permission="deny")]
        else:
            own = [egress, graph_read,
                   rule(f"gcs_{node.name}_read", ["declare_subscriber"], [f"{p}**"]),
                   rule(f"gcs_{node.name}_own", ["put", "delete", "declare_queryable", "reply", "query"],
                        [f"{p}{node.name}/**", f"{p}@srv/{node.name}/**"]),
                   rule(f"gcs_{node.name}_graph", ["liveliness_token"], [f"{p}@zr/lv/**"])]
            if node.drones:
                own.append(rule(f"gcs_{node.name}_command", ["put", "query"],
                                [k for d in node.drones for k in (f"{p}{d}/setpoint", f"{p}@srv/{d}/**")]))
        policies.append({"id": f"policy_{node.name}", "rules": own, "subjects": [f"cn_{node.name}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
