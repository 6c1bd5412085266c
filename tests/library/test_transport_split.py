"""Best-effort samples really travel over the UDP link and reliable ones over TCP.

We look at what carried the bytes: the TCP link's own socket counters (``ss -ti``)
and the host's UDP datagram counter (/proc/net/snmp). Noise from other processes can
only add UDP datagrams, so each assertion is one that noise cannot make pass falsely.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import time

import pytest
from conftest import linked_configs, skip_unless_required, wait_for

from zenoh_robot import Node, QoSProfile
from zenoh_robot.msgs import String

N = 300
PAYLOAD = "x" * 2000   # under the 3 KB shared-memory threshold, over any keep-alive noise


def _udp_in_datagrams() -> int:
    lines = [line.split() for line in open("/proc/net/snmp") if line.startswith("Udp:")]
    return int(dict(zip(lines[0][1:], lines[1][1:], strict=True))["InDatagrams"])


def _tcp_bytes_sent(local_port: int) -> int:
    out = subprocess.run(["ss", "-tinH", "state", "established", f"( sport = :{local_port} )"],
                         capture_output=True, text=True, check=True).stdout
    m = re.search(r"bytes_sent:(\d+)", out)
    assert m, f"no TCP socket on port {local_port}: {out!r}"
    return int(m.group(1))


@pytest.mark.parametrize("reliability", ["best_effort", "reliable"])
def test_reliability_picks_the_link(ns: str, reliability: str) -> None:
    if shutil.which("ss") is None:
        skip_unless_required("iproute2's ss is missing: it reads the TCP socket counters (`make sysdeps`)")
    # Explicit endpoints, no scouting: the test must not depend on other Zenoh peers on the host.
    rx_cfg, tx_cfg = linked_configs()
    with Node("rx", namespace=ns, config=rx_cfg) as rx, Node("tx", namespace=ns, config=tx_cfg) as tx:
        peer = rx.session.zid()
        assert wait_for(lambda: len([l for l in tx.session.info.links() if l.zid == peer]) == 2, 10.0), \
            [str(l) for l in tx.session.info.links()]
        links = [l for l in tx.session.info.links() if l.zid == peer]
        tcp = next(l for l in links if l.src.startswith("tcp/"))
        assert any(l.src.startswith("udp/") and not l.is_streamed for l in links)
        tcp_port = int(tcp.src.rsplit(":", 1)[1])

        got = []
        profile = QoSProfile(reliability=reliability, depth=N)
        rx.create_subscription(String, "bulk", got.append, profile)
        pub = tx.create_publisher(String, "bulk", profile)
        time.sleep(0.3)
        tcp0, udp0 = _tcp_bytes_sent(tcp_port), _udp_in_datagrams()
        for _ in range(N):
            pub.publish(String(PAYLOAD))
            time.sleep(0.001)
        rx.spin_until(lambda: len(got) >= N * 0.9, 5.0)
        tcp_delta, udp_delta = _tcp_bytes_sent(tcp_port) - tcp0, _udp_in_datagrams() - udp0

    assert len(got) >= N * 0.9
    if reliability == "best_effort":
        assert udp_delta >= N * 0.9, f"only {udp_delta} UDP datagrams for {N} best-effort samples"
        assert tcp_delta < N * len(PAYLOAD) / 10, f"TCP carried {tcp_delta} bytes of best-effort data"
    else:
        assert tcp_delta >= N * len(PAYLOAD), f"TCP carried only {tcp_delta} bytes of reliable data"
