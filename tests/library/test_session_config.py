"""Session configuration: validation at start (never a hang), JSON5 files, shared-memory policy."""
from __future__ import annotations

from pathlib import Path

import pytest

from zenoh_robot import Node, SessionConfig, SessionConfigError

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("endpoint,match", [
    ("tcp127.0.0.1:7447", "expected PROTOCOL/HOST:PORT"),
    ("tcpx/127.0.0.1:7447", "unknown protocol"),
    ("tcp/127.0.0.1", "missing ':PORT'"),
    ("udp/127.0.0.1:99999", "port '99999'"),
])
def test_bad_endpoints_are_rejected(endpoint: str, match: str) -> None:
    with pytest.raises(SessionConfigError, match=match):
        SessionConfig(listen=[endpoint])


def test_unbindable_endpoint_fails_at_open_not_hangs() -> None:
    with pytest.raises(SessionConfigError, match="cannot open Zenoh session"):
        Node("n", config=SessionConfig(listen=["tcp/203.0.113.7:7447"]))


def test_mode_is_checked() -> None:
    with pytest.raises(SessionConfigError, match="mode 'server'"):
        SessionConfig(mode="server")


def test_shared_memory_only_on_loopback_unless_asked() -> None:
    assert SessionConfig.localhost().shared_memory_enabled
    assert not SessionConfig().shared_memory_enabled                       # 0.0.0.0: may cross hosts
    assert not SessionConfig(connect=["tcp/10.0.0.2:7447"], listen=[]).shared_memory_enabled
    assert SessionConfig(shared_memory=True).shared_memory_enabled


def test_shipped_json5_configs_load() -> None:
    peer = SessionConfig.from_file(ROOT / "configs" / "zenoh" / "peer.json5")
    assert peer.mode == "peer" and peer.listen == ["tcp/0.0.0.0:0"] and peer.max_links == 2
    assert "udp" not in peer.to_zenoh().get_json("transport/link/protocols")   # UDP only where asked for
    client = SessionConfig.from_file(ROOT / "configs" / "zenoh" / "client.json5")
    assert client.mode == "client" and client.connect and not client.multicast_scouting
    router = SessionConfig.from_file(ROOT / "configs" / "zenoh" / "router.json5")
    assert router.mode == "router"


def test_missing_or_broken_file(tmp_path: Path) -> None:
    with pytest.raises(SessionConfigError, match="does not exist"):
        SessionConfig.from_file(tmp_path / "none.json5")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(SessionConfigError, match="bad.json5"):
        SessionConfig.from_file(bad)


def test_resilient_transport_and_its_file_agree(tmp_path: Path) -> None:
    import json
    cfg = SessionConfig.resilient("wlan0")
    assert cfg.listen == ["udp/239.255.74.71:7460#iface=wlan0"] and not cfg.shared_memory_enabled
    nested = cfg.to_json5()
    assert nested["transport"]["link"]["tx"] == {"batch_size": 1300, "lease": 10000, "keep_alive": 100}
    assert nested["transport"]["multicast"]["join_interval"] == 250
    path = tmp_path / "r.json5"
    path.write_text(json.dumps(nested))
    back = SessionConfig.from_file(path)
    assert back.listen == cfg.listen and back.mode == "peer" and not back.multicast_scouting
    shipped = SessionConfig.from_file(ROOT / "configs" / "zenoh" / "resilient.json5")
    assert shipped.listen[0].startswith("udp/239.255.74.71:7460")


def test_lossy_unicast_dials_udp_first_and_redials_a_lost_tcp_link_slowly() -> None:
    """Across 50-70 % loss a TCP link dies (lease) and fast re-dials of it froze or ended the session
    (docs/lossy-link.md, unicast): the lossy settings dial it at start-up, then every 5 s -> 60 s."""
    import dataclasses
    import json

    from drone_contract.streams import stream_profile
    from zenoh_robot.session_config import LOSSY_LINK

    slow = "retry_period_increase_factor=2;retry_period_init_ms=5000;retry_period_max_ms=60000"
    profile = stream_profile("resilient").session_config()
    assert profile.lossy
    for cfg in (SessionConfig(**LOSSY_LINK, listen=[], connect=["tcp/10.0.0.1:7447", "udp/10.0.0.1:7447"]),
                dataclasses.replace(profile, listen=[], connect=["tcp/10.0.0.1:7447", "udp/10.0.0.1:7447"])):
        assert cfg.to_json5()["connect"]["endpoints"] == ["udp/10.0.0.1:7447", f"tcp/10.0.0.1:7447#{slow}"]
        assert f"tcp/10.0.0.1:7447#{slow}" in json.loads(cfg.to_zenoh().get_json("connect/endpoints"))
    # A key the user wrote wins; the rest of the endpoint's config part stays.
    own = SessionConfig(**LOSSY_LINK, connect=["tls/10.0.0.1:7447#iface=eth0;retry_period_init_ms=100"])
    assert own.to_json5()["connect"]["endpoints"] == [
        "tls/10.0.0.1:7447#iface=eth0;retry_period_increase_factor=2;retry_period_init_ms=100;"
        "retry_period_max_ms=60000"]
    # Without ``lossy`` (a plain session) the endpoints are Zenoh's as given.
    plain = SessionConfig(connect=["tcp/10.0.0.1:7447", "udp/10.0.0.1:7447"])
    assert plain.to_json5()["connect"]["endpoints"] == ["tcp/10.0.0.1:7447", "udp/10.0.0.1:7447"]
