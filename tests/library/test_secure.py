"""Secure sessions: TLS/QUIC with mutual authentication against our CA, and the role ACL.

Every test runs a real secure router on a loopback port and real client sessions, as the
brief's rogue peer did: a default session, one with a certificate from another CA, and ones
with valid certificates of the wrong role. Each rogue attempt is followed by the legitimate
GCS's, so a test that sees nothing because nothing works at all fails.
"""
from __future__ import annotations

import json
import stat
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import free_port, wait_for

import zenoh_robot.tools.keys as keys
from zenoh_robot.session_config import SessionConfig, SessionConfigError  # noqa: E402

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

SETTLE = 0.6     # long enough for a put to cross two loopback hops many times over


@pytest.fixture(scope="module")
def keys_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("keys")
    keys.init_ca(d)
    keys.issue(d, "router", "router")
    keys.issue(d, "gcs", "gcs", drones=["uav1"])
    keys.issue(d, "gcs2", "gcs", drones=["uav2"])
    keys.issue(d, "uav1", "drone")
    keys.issue(d, "uav2", "drone")
    return d


@pytest.fixture(scope="module")
def evil_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Another CA issuing a certificate with the GCS's very name."""
    d = tmp_path_factory.mktemp("evil")
    keys.init_ca(d, name="evil CA")
    keys.issue(d, "gcs", "gcs", drones=["uav1"])
    return d


def _open(config: SessionConfig) -> zenoh.Session:
    return zenoh.open(config.to_zenoh())


def secure_client(keys_dir: Path, name: str, endpoint: str, **kw: Any) -> zenoh.Session:
    return _open(SessionConfig(secure=str(keys_dir), name=name, mode="client", listen=[], connect=[endpoint],
                               multicast_scouting=False, **kw))


class Drone:
    """The legitimate drone side: records setpoints and command queries that reach it."""

    def __init__(self, session: zenoh.Session, drone_id: str = "uav1") -> None:
        self.session = session
        self.setpoints: list[bytes] = []
        self.commands: list[bytes] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(f"{drone_id}/setpoint", self._on_setpoint)
        self._srv = session.declare_queryable(f"@srv/{drone_id}/command", self._on_query)
        self.key = f"@srv/{drone_id}/command"

    def _on_setpoint(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.setpoints.append(sample.payload.to_bytes())

    def _on_query(self, query: zenoh.Query) -> None:
        with self._lock:
            self.commands.append(query.payload.to_bytes() if query.payload else b"")
        query.reply(self.key, b"accepted")


def attack(session: zenoh.Session, tag: bytes, drone_id: str = "uav1") -> list[bytes]:
    """What the brief's rogue did: a setpoint and an arm command; returns any replies it got."""
    session.put(f"{drone_id}/setpoint", tag)
    replies = session.get(f"@srv/{drone_id}/command", payload=tag, timeout=1.0)
    return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]


@pytest.fixture
def system(keys_dir: Path) -> Iterator[tuple[str, Drone, zenoh.Session]]:
    """A secure router, the drone (uav1) and its GCS as clients of it."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = _open(SessionConfig(secure=str(keys_dir), name="router", mode="router", listen=[endpoint],
                                 multicast_scouting=False))
    drone_session = secure_client(keys_dir, "uav1", endpoint)
    gcs = secure_client(keys_dir, "gcs", endpoint)
    drone = Drone(drone_session)
    time.sleep(0.3)   # declarations reach the router
    try:
        yield endpoint, drone, gcs
    finally:
        for s in (gcs, drone_session, router):
            s.close()


def assert_gcs_still_reaches(drone: Drone, gcs: zenoh.Session) -> None:
    before = len(drone.setpoints)
    assert attack(gcs, b"gcs") == [b"accepted"]
    assert wait_for(lambda: len(drone.setpoints) > before, 3.0)
    assert drone.setpoints[-1] == b"gcs"


def test_gcs_reaches_its_drone_and_reads_its_state(system: tuple[str, Drone, zenoh.Session]) -> None:
    _, drone, gcs = system
    seen: list[str] = []
    gcs.declare_subscriber("*/state", lambda s: seen.append(str(s.key_expr)))
    time.sleep(0.3)
    drone.session.put("uav1/state", b"armed")
    assert_gcs_still_reaches(drone, gcs)
    assert wait_for(lambda: "uav1/state" in seen, 3.0)


def test_default_session_cannot_connect(system: tuple[str, Drone, zenoh.Session]) -> None:
    endpoint, drone, gcs = system
    port = endpoint.rsplit(":", 1)[1]
    for rogue_ep in (f"tcp/127.0.0.1:{port}", endpoint):   # plain TCP, and TLS without a client certificate
        conf = zenoh.Config()
        conf.insert_json5("connect/endpoints", json.dumps([rogue_ep]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        rogue = zenoh.open(conf)
        try:
            assert attack(rogue, b"rogue") == []
            time.sleep(SETTLE)
            assert list(rogue.info.routers_zid()) == [] and list(rogue.info.peers_zid()) == []
        finally:
            rogue.close()
    assert b"rogue" not in drone.setpoints and b"rogue" not in drone.commands
    assert_gcs_still_reaches(drone, gcs)


def test_certificate_from_another_ca_cannot_connect(system: tuple[str, Drone, zenoh.Session],
                                                   evil_dir: Path) -> None:
    endpoint, drone, gcs = system
    conf = SessionConfig(secure=str(evil_dir), name="gcs", mode="peer", listen=[], connect=[endpoint],
                         multicast_scouting=False)
    rogue = _open(conf)
    try:
        assert attack(rogue, b"evil") == []
        time.sleep(SETTLE)
        assert list(rogue.info.routers_zid()) == []
    finally:
        rogue.close()
    assert b"evil" not in drone.setpoints and b"evil" not in drone.commands
    assert_gcs_still_reaches(drone, gcs)


@pytest.mark.parametrize("name", ["uav2", "uav1", "gcs2"])
def test_valid_certificate_of_another_role_is_denied(system: tuple[str, Drone, zenoh.Session], keys_dir: Path,
                                                     name: str) -> None:
    """Another drone, a second process holding the drone's own certificate, a GCS of other drones."""
    endpoint, drone, gcs = system
    rogue = secure_client(keys_dir, name, endpoint)
    try:
        assert list(rogue.info.routers_zid()), "a valid certificate must connect: the ACL is what denies"
        time.sleep(0.2)
        assert attack(rogue, name.encode()) == []
        time.sleep(SETTLE)
    finally:
        rogue.close()
    assert name.encode() not in drone.setpoints and name.encode() not in drone.commands
    assert_gcs_still_reaches(drone, gcs)


def test_drone_cannot_publish_outside_its_namespace(system: tuple[str, Drone, zenoh.Session],
                                                    keys_dir: Path) -> None:
    endpoint, drone, gcs = system
    seen: list[str] = []
    gcs.declare_subscriber("**", lambda s: seen.append(str(s.key_expr)))
    other = secure_client(keys_dir, "uav2", endpoint)
    try:
        time.sleep(0.3)
        other.put("uav1/state", b"spoofed")      # pretending to be uav1
        other.put("uav2/state", b"own")          # its own namespace: allowed
        assert wait_for(lambda: "uav2/state" in seen, 3.0)
        time.sleep(0.2)
    finally:
        other.close()
    assert "uav1/state" not in seen


def test_quic_link_is_secure_too(keys_dir: Path, evil_dir: Path) -> None:
    endpoint = f"quic/127.0.0.1:{free_port()}"
    router = _open(SessionConfig(secure=str(keys_dir), name="router", mode="router", listen=[endpoint],
                                 multicast_scouting=False))
    sessions = [secure_client(keys_dir, "uav1", endpoint), secure_client(keys_dir, "gcs", endpoint)]
    try:
        drone = Drone(sessions[0])
        rogue = _open(SessionConfig(secure=str(evil_dir), name="gcs", listen=[], connect=[endpoint],
                                    multicast_scouting=False))
        sessions.append(rogue)
        time.sleep(0.3)
        assert attack(rogue, b"evil") == []
        assert_gcs_still_reaches(drone, sessions[1])
        assert b"evil" not in drone.setpoints
    finally:
        for s in reversed(sessions):
            s.close()
        router.close()


# --- keys and config, no network ---------------------------------------------------------------

def test_issued_keys_are_private_and_named(keys_dir: Path) -> None:
    from cryptography import x509
    from cryptography.x509.oid import NameOID
    for name in ("ca", "router", "gcs", "uav1"):
        assert stat.S_IMODE((keys_dir / f"{name}.key").stat().st_mode) == 0o600
    cert = x509.load_pem_x509_certificate((keys_dir / "uav1.pem").read_bytes())
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "uav1"
    assert cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)[0].value == "drone"
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert {"uav1", "localhost"} <= set(san.get_values_for_type(x509.DNSName))
    roles = keys.load_roles(keys_dir)
    assert roles["gcs"].role == "gcs" and roles["gcs"].drones == ["uav1"] and roles["uav1"].role == "drone"
    listed = {c.name: c for c in keys.list_certs(keys_dir)}
    assert listed["gcs"].role == "gcs" and listed["gcs"].key_mode == 0o600


def test_keys_refuse_bad_requests(tmp_path: Path, keys_dir: Path) -> None:
    with pytest.raises(keys.KeysError, match="no CA"):
        keys.issue(tmp_path, "uav1", "drone")
    with pytest.raises(keys.KeysError, match="ca.pem exists"):
        keys.init_ca(keys_dir)
    with pytest.raises(keys.KeysError, match="role"):
        keys.issue(keys_dir, "x", "admin")
    with pytest.raises(keys.KeysError, match="invalid node name"):
        keys.issue(keys_dir, "../etc", "drone")
    with pytest.raises(keys.KeysError, match="--drones is for a gcs"):
        keys.issue(keys_dir, "uav3", "drone", drones=["uav1"])


def test_secure_config_refuses_what_cannot_be_secure(keys_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(SessionConfigError, match="plain links"):
        SessionConfig(secure=str(keys_dir), name="gcs", listen=["tcp/127.0.0.1:0"])
    with pytest.raises(SessionConfigError, match="name="):
        SessionConfig(secure=str(keys_dir))
    with pytest.raises(SessionConfigError, match="missing"):
        SessionConfig(secure=str(tmp_path), name="gcs")
    conf = SessionConfig.secured(keys_dir, "gcs")
    values = conf.to_json5()
    assert conf.listen == ["tls/0.0.0.0:0"] and conf.shared_memory_enabled is False
    assert values["transport"]["link"]["tls"]["enable_mtls"] is True
    assert values["transport"]["link"]["protocols"] == ["tls", "quic"]
    assert values["access_control"]["default_permission"] == "deny"


def test_secure_flags_make_plain_profiles_secure_twins(keys_dir: Path) -> None:
    """--secure turns tcp into tls and unicast udp into QUIC with datagrams for best effort; multicast goes."""
    import argparse

    from zenoh_robot.session_args import session_config_from_args
    port = free_port()
    profile = SessionConfig(listen=[f"udp/127.0.0.1:{port}", "udp/239.255.74.71:7460#iface=lo"],
                            multicast_scouting=False)
    args = argparse.Namespace(secure=str(keys_dir))
    drone = session_config_from_args(args, profile, "uav1")
    assert drone.listen == [f"quic/127.0.0.1:{port}?mixed_rel=auto"] and drone.name == "uav1"
    args.connect = [f"udp/127.0.0.1:{port}", "tcp/127.0.0.1:7447"]
    gcs = session_config_from_args(args, SessionConfig(listen=[], multicast_scouting=False), "gcs")
    assert gcs.connect == [f"quic/127.0.0.1:{port}?mixed_rel=auto", "tls/127.0.0.1:7447"]
    gcs.connect = gcs.connect[:1]
    sessions = [_open(drone), _open(gcs)]
    try:
        # One QUIC connection, two Zenoh links: a stream (reliable) and datagrams (best effort).
        assert wait_for(lambda: len(list(sessions[1].info.links())) == 2, 5.0)
        kinds = {(str(lk.reliability), lk.is_streamed) for lk in sessions[1].info.links()}
        assert kinds == {("Reliability.RELIABLE", True), ("Reliability.BEST_EFFORT", False)}, kinds
    finally:
        for s in reversed(sessions):
            s.close()


def test_put_carried_calls_pass_the_acl_for_their_owners_only(system: tuple[str, Drone, zenoh.Session],
                                                               keys_dir: Path) -> None:
    """services.py's put-carried path (<key>/@rq, <key>/@rp/<client>): '**' in a rule never matches
    those verbatim chunks, so the ACL names them; another drone's GCS still cannot reach the request key."""
    endpoint, drone, gcs = system
    requests: list[bytes] = []
    replies: list[bytes] = []
    drone.session.declare_subscriber(f"{drone.key}/@rq", lambda s: requests.append(s.payload.to_bytes()))
    gcs.declare_subscriber(f"{drone.key}/@rp/*", lambda s: replies.append(s.payload.to_bytes()))
    rogue = secure_client(keys_dir, "gcs2", endpoint)
    try:
        time.sleep(0.3)
        rogue.put(f"{drone.key}/@rq", b"rogue")
        gcs.put(f"{drone.key}/@rq", b"arm")
        assert wait_for(lambda: b"arm" in requests, 3.0)
        drone.session.put(f"{drone.key}/@rp/client1", b"accepted")
        assert wait_for(lambda: replies == [b"accepted"], 3.0)
        time.sleep(SETTLE)
        assert b"rogue" not in requests
    finally:
        rogue.close()
