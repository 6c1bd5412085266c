"""UDP links only where a session is given a ``udp/`` endpoint (docs/architecture.md, "UDP only where asked for").

Zenoh sends reliable messages on any link while a transport has no reliable one, and a transport a peer
opened through our UDP locator carried its first declarations over UDP: one datagram the host dropped
(receive buffer full beside ~30 peers) lost a token or subscriber declaration for the transport's life, so a
CLI never saw a running talker (6 of ~860 start-ups before; 0 of 700 with TCP only). A session given no
``udp/`` endpoint now listens on TCP only and never dials a peer's UDP locator; one that lists UDP keeps
the TCP + UDP split.
"""
from __future__ import annotations

import json
import time

import pytest
from conftest import free_port, wait_for

from zenoh_robot import SessionConfig
from zenoh_robot.session_config import LINK_PROTOCOLS, open_session


def _protocols(config: SessionConfig) -> object:
    return json.loads(config.to_zenoh().get_json(LINK_PROTOCOLS))


@pytest.mark.fast
def test_a_session_given_no_udp_endpoint_neither_listens_on_nor_dials_udp(tmp_path) -> None:
    default = SessionConfig()
    assert default.listen == ["tcp/0.0.0.0:0"]
    assert "udp" not in _protocols(default) and "tcp" in _protocols(default) and "quic" in _protocols(default)
    assert "udp" not in _protocols(SessionConfig.localhost())
    # Asked for: the split (TCP reliable, UDP best effort), the resilient multicast transport, a lossy unicast.
    assert _protocols(SessionConfig(listen=["tcp/127.0.0.1:0", "udp/127.0.0.1:0"])) is None
    assert _protocols(SessionConfig.resilient("lo")) is None
    assert _protocols(SessionConfig(listen=[], connect=["udp/10.0.0.1:7447", "tcp/10.0.0.1:7447"], lossy=True)) is None
    # A whitelist of the user's own stands: in ``extra``, or in a --zenoh file.
    assert _protocols(SessionConfig(extra={LINK_PROTOCOLS: ["tcp", "udp"]})) == ["tcp", "udp"]
    own = tmp_path / "own.json5"
    own.write_text('{ mode: "peer", transport: { link: { protocols: ["tcp", "udp"] } } }')
    assert _protocols(SessionConfig.from_file(own)) == ["tcp", "udp"]


def test_a_default_session_holds_only_tcp_to_a_peer_that_advertises_udp_first() -> None:
    """The peer lists UDP before TCP (as a Hello may): before, the default session dialled its UDP locator
    first, and the transport carried declarations over UDP until the other side's TCP link joined it."""
    scouting = {"scouting/multicast/address": f"224.0.0.224:{free_port()}"}   # a group port of this test's own
    udp_first = SessionConfig(listen=[f"udp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"],
                              shared_memory=False, extra=scouting)
    a = open_session(udp_first)
    try:
        b = open_session(SessionConfig(shared_memory=False, extra=scouting))
        try:
            peer = str(a.zid())
            assert wait_for(lambda: any(str(link.zid) == peer for link in b.info.links()), 15.0), "never met"
            time.sleep(1.5)     # the window in which no UDP link may appear: both ends' scouted dials
            links = [(str(link.src), str(link.reliability)) for link in b.info.links() if str(link.zid) == peer]
            assert links and all(src.startswith("tcp/") for src, _ in links), links
        finally:
            b.close()
    finally:
        a.close()
