"""A lossy unicast session never re-dials a lost TCP link in a hurry (issue #29, docs/lossy-link.md).

Flown over unicast at 50-70 % loss, the resilient profile's session (UDP + TCP links) lost the link for
seconds in 3 of 6 runs. The TCP link dies first (its backed-off retransmissions outlast the 10 s lease);
the session lives on over UDP, but a peer then re-dialled the TCP endpoint every 50-200 ms, and a
re-dial half accepted across the loss froze both Zenoh runtimes for seconds or ended the session.
The product's lossy settings (``SessionConfig.lossy``: ``slow_redial``) dial the TCP link at start-up
and then at most every 5 s -> 60 s.

Real sessions in two network namespaces, real bytes: the link is clean, both links form, then every
TCP segment is dropped (nftables) so the TCP link's lease expires deterministically (a 2 s lease here,
keep-alives every 100 ms, so the test takes seconds, not the product's 10 s). The drone's SYNs to the
GCS's TCP port are counted by an nftables counter: with the old settings about 2 per second (each
250 ms try retried after 50-200 ms), now none (Zenoh 1.10 does not re-dial an endpoint written with a
config part) or at most 2 (a Zenoh that did: at once, then after 5 s). The UDP link carries the
samples both ways through it. Needs root; with ZR_REQUIRE_NETNS=1 (CI) a missing capability fails it.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import skip_unless_required, wait_for

from drone_lab.experiment.netns import LossyLink, unavailable_reason

ROOT = Path(__file__).resolve().parents[2]
PORT = 7447
LEASE_S = 2.0
BLOCKED_S = 8.0        # the TCP link dies after LEASE_S; the old settings then re-dial ~2 times a second
RUN_S = 16.0

SIDE = """
import dataclasses, json, sys, time
from drone_contract.streams import stream_profile
from zenoh_robot.session_config import open_session
role, gcs, lease, run_s = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
endpoints = [f"udp/{gcs}:7447", f"tcp/{gcs}:7447"]
# The profile's session as `--listen`/`--connect` make it (zenoh_robot.session_args); only the lease is
# shorter, so the TCP link's expiry takes seconds.
base = dataclasses.replace(stream_profile("resilient").session_config(), multicast_scouting=False,
                           shared_memory=False, lease_s=lease, keep_alive=int(lease * 10))
if role == "gcs":
    cfg = dataclasses.replace(base, listen=endpoints)
else:
    cfg = dataclasses.replace(base, listen=[], connect=endpoints)
session = open_session(cfg)
mine, theirs = ("zr29/down", "zr29/up") if role == "gcs" else ("zr29/up", "zr29/down")
arrivals = []
sub = session.declare_subscriber(theirs, lambda s: arrivals.append(time.time()))
pub = session.declare_publisher(mine)
print("READY", flush=True)
end = time.monotonic() + run_s
said = False
while time.monotonic() < end:
    pub.put(b"x" * 64)
    if arrivals and not said:
        print("HEARD", flush=True)
        said = True
    time.sleep(0.05)
print("ARRIVALS " + json.dumps(arrivals), flush=True)
session.close()
"""

TABLE = "zrredial"


def _nft(link: LossyLink, side: str, script: str) -> None:
    subprocess.run(link.exec_in(side) + ["nft", "-f", "-"], input=script, capture_output=True, text=True, check=True)


def _count_syns(link: LossyLink) -> None:
    """Count every SYN the drone sends to the GCS's TCP port (before the GCS's rule drops it)."""
    _nft(link, "drone", f"table inet {TABLE} {{\n chain out {{\n  type filter hook output priority 0; policy accept;\n"
                        f"  tcp dport {PORT} tcp flags & (syn | ack) == syn counter\n }}\n}}\n")


def _block_tcp(link: LossyLink) -> None:
    for side, match in (("gcs", f"tcp dport {PORT}"), ("drone", f"tcp sport {PORT}")):
        _nft(link, side, f"table inet {TABLE}b {{\n chain pre {{\n  type filter hook prerouting priority -500;"
                         f" policy accept;\n  {match} drop\n }}\n}}\n")


def _syns(link: LossyLink) -> int:
    out = subprocess.run(link.exec_in("drone") + ["nft", "list", "table", "inet", TABLE],
                         capture_output=True, text=True, check=True).stdout
    m = re.search(r"counter packets (\d+)", out)
    assert m, out
    return int(m.group(1))


def _tcp_established(link: LossyLink) -> bool:
    out = subprocess.run(link.exec_in("drone") + ["ss", "-Htn", "state", "established", f"( dport = :{PORT} )"],
                         capture_output=True, text=True, check=True).stdout
    return bool(out.strip())


def _wait_line(proc: subprocess.Popen[str], want: str, timeout: float) -> None:
    assert proc.stdout is not None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if line.strip() == want:
            return
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"no {want} line within {timeout} s")


def _arrivals(proc: subprocess.Popen[str]) -> list[float]:
    out, _ = proc.communicate(timeout=30)
    line = next(x for x in out.splitlines() if x.startswith("ARRIVALS "))
    return [float(t) for t in json.loads(line.split(" ", 1)[1])]


@pytest.mark.netns
def test_a_lost_tcp_link_is_not_redialled_in_a_hurry_and_udp_carries_on() -> None:
    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"unicast re-dial test: network namespaces are unavailable: {reason}")
    with LossyLink(loss_pct=0) as link:
        gcs = link.addr("gcs")
        args = [gcs, str(LEASE_S)]
        listener = subprocess.Popen(link.exec_in("gcs") + [sys.executable, "-c", SIDE, "gcs", *args, str(RUN_S + 2)],
                                    stdout=subprocess.PIPE, text=True, cwd=ROOT)
        connector = subprocess.Popen(link.exec_in("drone") + [sys.executable, "-c", SIDE, "drone", *args, str(RUN_S)],
                                     stdout=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            _wait_line(listener, "READY", 20)
            _wait_line(connector, "HEARD", 20)
            # The TCP endpoint is dialled beside the UDP one at start-up: once, within a few seconds.
            assert wait_for(lambda: _tcp_established(link), 10.0), "the TCP link did not form on a clean link"
            _count_syns(link)
            _block_tcp(link)
            blocked = time.time()
            time.sleep(BLOCKED_S)
            syns = _syns(link)
            down, up = _arrivals(connector), _arrivals(listener)
        finally:
            for p in (listener, connector):
                if p.poll() is None:
                    p.kill()
                    p.wait()
    assert syns <= 2, f"the drone re-dialled the dead TCP link {syns} times in {BLOCKED_S:g} s"
    # The session outlived its TCP link: samples crossed both ways after the link's lease had expired.
    after = blocked + LEASE_S + 1.0
    assert sum(t > after for t in down) > 20 and sum(t > after for t in up) > 20, \
        (sum(t > after for t in down), sum(t > after for t in up))
