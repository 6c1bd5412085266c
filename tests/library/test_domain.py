"""Domains keep systems on one network apart; a node name alive in a domain cannot start twice."""
from __future__ import annotations

import time

import pytest
from conftest import free_port

from zenoh_robot import Node
from zenoh_robot.graph import DuplicateNodeError
from zenoh_robot.msgs import String
from zenoh_robot.session_config import SessionConfig, SessionConfigError, resolve_domain

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def _pair(domain: int, port: int) -> tuple[SessionConfig, SessionConfig]:
    """Listener and connector on loopback."""
    listen = SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, domain=domain)
    connect = SessionConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, domain=domain)
    return listen, connect


def test_two_systems_in_different_domains_on_one_network_do_not_interfere(ns: str) -> None:
    """Both systems are linked to one another (same Zenoh network) and use the same names."""
    hub_a, hub_b = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"

    def conf(domain: int, listen: list[str], connect: list[str]) -> SessionConfig:
        return SessionConfig(listen=listen, connect=connect, multicast_scouting=False, domain=domain)

    # One mesh: every session is linked to both drones' sessions, whatever its domain.
    nodes = {
        "a_drone": Node("companion", namespace=ns, config=conf(3, [hub_a], [])),
        "b_drone": Node("companion", namespace=ns, config=conf(4, [hub_b], [hub_a])),
        "a_gcs": Node("gcs", config=conf(3, [], [hub_a, hub_b])),
        "b_gcs": Node("gcs", config=conf(4, [], [hub_a, hub_b])),
    }
    try:
        got: dict[str, list[str]] = {"a": [], "b": []}
        for side in ("a", "b"):
            nodes[f"{side}_drone"].create_subscription(String, f"/{ns}/setpoint",
                                                       lambda m, side=side: got[side].append(m.data), 10)
        pubs = {side: nodes[f"{side}_gcs"].create_publisher(String, f"/{ns}/setpoint", 10) for side in ("a", "b")}
        time.sleep(0.5)
        for i in range(5):
            pubs["a"].publish(String(f"a{i}"))
            pubs["b"].publish(String(f"b{i}"))
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and not (len(got["a"]) == 5 and len(got["b"]) == 5):
            nodes["a_drone"].spin_once(timeout=0.05)
            nodes["b_drone"].spin_once(timeout=0.05)
        for _ in range(4):   # anything from the other domain would be queued by now
            nodes["a_drone"].spin_once(timeout=0.05)
            nodes["b_drone"].spin_once(timeout=0.05)
        assert got["a"] == [f"a{i}" for i in range(5)] and got["b"] == [f"b{i}" for i in range(5)]
        # The graph is per domain too: each GCS sees one companion, its own.
        nodes["a_gcs"].refresh_graph()
        assert sum(1 for n, s in nodes["a_gcs"].get_node_names_and_namespaces() if n == "companion") == 1
        # Same fully qualified name in two domains is no duplicate.
    finally:
        for n in nodes.values():
            n.close()


def test_duplicate_node_name_refuses_to_start(ns: str) -> None:
    port = free_port()
    listen, connect = _pair(0, port)
    first = Node("companion", namespace=ns, config=listen)
    try:
        with pytest.raises(DuplicateNodeError) as err:
            Node("companion", namespace=ns, config=connect)
        text = str(err.value)
        assert f"/{ns}/companion" in text and str(first.session.info.zid()) in text and "127.0.0.1" in text
        other = Node("companion2", namespace=ns, config=connect)    # another name is fine
        other.close()
    finally:
        first.close()


def test_domain_from_env_and_bounds(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ZR_DOMAIN", "7")
    assert SessionConfig().domain == 7 and SessionConfig().to_json5()["namespace"] == "zr7"
    assert SessionConfig(domain=0).to_json5().get("namespace") is None     # domain 0: historic keys
    monkeypatch.setenv("ZR_DOMAIN", "x")
    with pytest.raises(SessionConfigError, match="ZR_DOMAIN"):
        SessionConfig()
    with pytest.raises(SessionConfigError, match="0..232"):
        resolve_domain(233)
