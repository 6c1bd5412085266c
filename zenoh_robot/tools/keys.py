"""A small certificate authority for a zenoh-robot system, and the access rules it implies.

``init`` makes a CA in a keys directory; ``issue`` makes a node's key and certificate, signed
by that CA, with CN = node name (Zenoh's ACL matches subjects by ``cert_common_names``) and
OU = role; ``roles.yaml`` in the same directory records who is what (and which drones a GCS
controls), because an ACL is generated from it (:func:`acl_config`) when a session opens.
Private keys are written 0600 and never leave the directory.

Layout of DIR::

    ca.pem ca.key            the CA (ca.key signs; keep it off the vehicles)
    <name>.pem <name>.key    a node's certificate and key
    roles.yaml               {nodes: {<name>: {role: gcs|drone|router, drones: [...]}}}
    link/<name>.json         a node's link keyring (sealed samples, ``keys link``; zenoh_robot.keyring)
    link/revoked.json        revoked link key ids

Needs the ``secure`` extra (``cryptography``); importing this module without it raises an
ImportError that says so.
"""
from __future__ import annotations

import datetime as dt
import fcntl
import ipaddress
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from zenoh_robot.acl import ROLES, KeysError, NodeEntry, acl_config, check_name, domain_prefix, load_roles, save_roles
from zenoh_robot.keyring import FLEET
from zenoh_robot.loss_feedback import LINK_TOPIC

try:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
except ImportError as exc:   # pragma: no cover - depends on the install
    raise ImportError("zenoh-robot keys needs the 'secure' extra: pip install 'zenoh-robot[secure]'") from exc

# The access rules of zenoh_robot.acl are part of this module's interface (the CLI and scripts use them here).
__all__ = ["CA_DAYS", "NODE_DAYS", "ROLES", "CertInfo", "KeysError", "NodeEntry", "acl_config", "check_name",
           "domain_prefix", "init_ca", "issue", "list_certs", "load_roles", "make_link_keys", "revoke_link_keys",
           "save_roles", "write_node_config"]

CA_DAYS = 5 * 365           # the CA outlives a fleet's certificates; rotating it means re-issuing all
NODE_DAYS = 365             # a year: a lost vehicle's certificate stops working on its own


def _write_private(path: Path, data: bytes) -> None:
    # Created 0600 from the start: a chmod after writing leaves a window where others can read it.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def init_ca(keys_dir: str | Path, name: str = "zenoh-robot CA", days: int = CA_DAYS, force: bool = False) -> Path:
    """Create the CA in ``keys_dir``; refuses to overwrite one unless ``force``."""
    d = Path(keys_dir)
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    if (d / "ca.pem").exists() and not force:
        raise KeysError(f"{d}/ca.pem exists: a new CA would orphan every issued certificate (use --force)")
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "zenoh-robot")])
    now = _now()
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    _write_private(d / "ca.key", _key_pem(key))
    (d / "ca.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    if not (d / "roles.yaml").exists():
        save_roles(d, {})
    return d / "ca.pem"


def _load_ca(d: Path) -> tuple[x509.Certificate, Any]:
    if not (d / "ca.pem").is_file() or not (d / "ca.key").is_file():
        raise KeysError(f"no CA in {d}: run `zenoh-robot keys init {d}` first")
    cert = x509.load_pem_x509_certificate((d / "ca.pem").read_bytes())
    key = serialization.load_pem_private_key((d / "ca.key").read_bytes(), password=None)
    return cert, key


def issue(keys_dir: str | Path, name: str, role: str, drones: list[str] | None = None,
          sans: list[str] | None = None, days: int = NODE_DAYS) -> Path:
    """Issue ``name``'s key and certificate (CN=name, OU=role) and record its role; returns the cert path.

    SANs: the node name, ``localhost`` and ``127.0.0.1`` always, plus ``sans`` (the host names or
    addresses others dial to reach it, needed where names are verified on connect).
    """
    d = Path(keys_dir)
    check_name(name)
    if role not in ROLES:
        raise KeysError(f"role {role!r}: choose one of {', '.join(ROLES)}")
    drones = [check_name(x, "drone name") for x in (drones or [])]
    if drones and role != "gcs":
        raise KeysError("--drones is for a gcs: the drones it may command")
    ca_cert, ca_key = _load_ca(d)
    key = ec.generate_private_key(ec.SECP256R1())
    alt: list[x509.GeneralName] = [x509.DNSName(name), x509.DNSName("localhost"),
                                   x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
    for san in sans or []:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(san)))
        except ValueError:
            alt.append(x509.DNSName(san))
    now = _now()
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name),
                                     x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, role),
                                     x509.NameAttribute(NameOID.ORGANIZATION_NAME, "zenoh-robot")]))
            .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(min(now + dt.timedelta(days=days), ca_cert.not_valid_after_utc))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            # Every node both listens (server) and dials (client): peers, and routers linking routers.
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    _write_private(d / f"{name}.key", _key_pem(key))
    (d / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    # Read-modify-write under a lock: two `keys issue` run at once (a script issuing a fleet)
    # must not lose each other's entry, or a node with a valid certificate has no role at all.
    with open(d / ".roles.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        nodes = load_roles(d)
        nodes[name] = NodeEntry(name, role, drones)
        save_roles(d, nodes)
    return d / f"{name}.pem"


@dataclass
class CertInfo:
    name: str
    role: str
    not_after: dt.datetime
    issuer: str
    key_mode: int | None


def list_certs(keys_dir: str | Path) -> list[CertInfo]:
    d = Path(keys_dir)
    out = []
    for pem in sorted(d.glob("*.pem")):
        if pem.name == "ca.pem":
            continue
        cert = x509.load_pem_x509_certificate(pem.read_bytes())
        cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        ou = cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)
        key = pem.with_suffix(".key")
        out.append(CertInfo(str(cn[0].value) if cn else pem.stem, str(ou[0].value) if ou else "?",
                            cert.not_valid_after_utc, cert.issuer.rfc4514_string(),
                            key.stat().st_mode & 0o777 if key.exists() else None))
    return out




def write_node_config(keys_dir: str | Path, name: str, mode: str | None = None) -> Path:
    """``DIR/<name>.json5``: a complete Zenoh config for ``name`` (certificates, mTLS, ACL), usable as
    ``--zenoh`` by any tool; routers listen on tls/0.0.0.0:7447, others are peers listening anywhere."""
    from zenoh_robot.session_config import SessionConfig

    d = Path(keys_dir)
    role = load_roles(d)[name].role
    mode = mode or ("router" if role == "router" else "peer")
    listen = ["tls/0.0.0.0:7447"] if role == "router" else ["tls/0.0.0.0:0"]
    conf = SessionConfig(secure=str(d), name=name, mode=mode, listen=listen, multicast_scouting=False)
    path = d / f"{name}.json5"
    path.write_text(f"// {name} ({role}), generated by `zenoh-robot keys issue`: re-issue to refresh the ACL.\n"
                    + json.dumps(conf.to_json5(), indent=2) + "\n")
    return path


# -- link keys: the symmetric keys of sealed samples (zenoh_robot.wire.sealed, zenoh_robot.keyring) ----------
LINK_DIR = "link"
LINK_MASTER = "keys.json"
FLEET_SCOPE = LINK_TOPIC.strip("/")     # the loss-feedback probes' key (outside every drone's namespace)
# A GCS's link key is named by its client id (what its setpoints and commands claim), and `gcs`
# defaults that to user@host: the contract's client id syntax, never "." or ".." (a file name).
_GCS_LINK_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.@:+-]{0,63}$")


def check_gcs_link_name(name: str) -> str:
    """``name`` if it can name a GCS's link keyring (a client id such as ``gcs1`` or ``pilot@ground``)."""
    if not isinstance(name, str) or not _GCS_LINK_NAME.match(name):
        raise KeysError(f"invalid GCS id {name!r}: letters, digits and _.@:+-, up to 64, not starting with . @ : + -")
    return name


def _link_entry(sender: str, role: str, scope: str) -> dict[str, Any]:
    return {"id": os.urandom(4).hex(), "sender": sender, "role": role, "scope": scope,
            "secret": os.urandom(32).hex(), "created": dt.datetime.now(dt.UTC).timestamp()}


def make_link_keys(keys_dir: str | Path, gcs: dict[str, list[str]] | None = None, drones: list[str] | None = None,
                   rotate: bool = False) -> list[Path]:
    """Make (or, with ``rotate``, add a newer generation of) the link keys of a fleet and write each
    node's keyring to ``<keys_dir>/link/<node>.json`` (0600); returns those paths.

    Nodes: ``roles.yaml`` (``keys issue``) plus ``gcs`` ({name: drones it commands}) and ``drones``.
    Keys: one per drone (it seals its telemetry; it and the GCSs commanding it hold it) and one per
    (GCS, drone) pair (the GCS seals its setpoints and commands to that drone; the two hold it). A
    rotated key is added, not swapped: old keys still open until :func:`drop_link_keys` removes them.
    The secrets live in ``link/keys.json`` (0600, the fleet's: keep it where ``ca.key`` is)."""
    d = Path(keys_dir)
    gcs_map = {n: list(e.drones) for n, e in load_roles(d).items() if e.role == "gcs"} if d.is_dir() else {}
    drone_set = {n for n, e in load_roles(d).items() if e.role == "drone"} if d.is_dir() else set()
    for name, ds in (gcs or {}).items():
        gcs_map[check_gcs_link_name(name)] = sorted({*gcs_map.get(name, []), *(check_name(x) for x in ds)})
    drone_set |= {check_name(x) for x in drones or []}
    drone_set |= {x for ds in gcs_map.values() for x in ds}
    if not drone_set:
        raise KeysError("keys link: no drones (give --drone/--gcs, or issue certificates with roles first)")
    link = d / LINK_DIR
    link.mkdir(parents=True, exist_ok=True)
    master_path = link / LINK_MASTER
    with open(link / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        keys: list[dict[str, Any]] = json.loads(master_path.read_text()) if master_path.exists() else []
        have = {(k["sender"], k["scope"]) for k in keys}
        wanted = [(FLEET, FLEET, FLEET_SCOPE)]     # the fleet's bookkeeping (loss probes): every node holds it
        wanted += [(x, "drone", x) for x in sorted(drone_set)]
        wanted += [(g, "gcs", x) for g, ds in sorted(gcs_map.items()) for x in ds]
        for sender, role, scope in wanted:
            if rotate or (sender, scope) not in have:
                keys.append(_link_entry(sender, role, scope))
        _write_private(master_path, json.dumps(keys, indent=1).encode())
        return _write_keyrings(link, keys, gcs_map, drone_set)


def _write_keyrings(link: Path, keys: list[dict[str, Any]], gcs_map: dict[str, list[str]],
                    drone_set: set[str]) -> list[Path]:
    paths = []
    for node in sorted(drone_set | set(gcs_map)):
        if node in gcs_map:
            mine = [k for k in keys if (k["sender"] == node) or (k["role"] == "drone" and k["scope"] in gcs_map[node])
                    or k["role"] == FLEET]
        else:
            mine = [k for k in keys if (k["scope"] == node and (k["sender"] == node or k["role"] == "gcs"))
                    or k["role"] == FLEET]
        path = link / f"{node}.json"
        _write_private(path, json.dumps({"node": node, "keys": mine}, indent=1).encode())
        paths.append(path)
    return paths


def revoke_link_keys(keys_dir: str | Path, ids_or_nodes: list[str]) -> list[str]:
    """Add the link keys named (by id, or every key a node sends with) to ``link/revoked.json``;
    nodes refuse samples under them within their keyring's refresh interval. Returns the ids."""
    link = Path(keys_dir) / LINK_DIR
    master_path = link / LINK_MASTER
    if not master_path.exists():
        raise KeysError(f"no link keys in {link} (zenoh-robot keys link first)")
    keys = json.loads(master_path.read_text())
    ids = sorted({k["id"] for k in keys if k["id"] in ids_or_nodes or k["sender"] in ids_or_nodes})
    if not ids:
        raise KeysError(f"no link key id or sender among {ids_or_nodes}")
    revoked_path = link / "revoked.json"
    revoked = json.loads(revoked_path.read_text()) if revoked_path.exists() else []
    tmp = link / "revoked.json.tmp"
    tmp.write_text(json.dumps(sorted({*revoked, *ids})))
    os.replace(tmp, revoked_path)     # atomic: a node never reads half a list
    return ids
