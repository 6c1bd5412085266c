"""The product carries what the experiment found (issue #29): a unicast session opened through the
public API (``stream_profile("resilient").session_config()`` with the endpoints a user passes) forms
across a lossy link from start-up, as the experiment's own tuned cells did.

A UDP link between two network namespaces with loss on from the first datagram. Zenoh 1.10's
unicast open is four datagrams, never re-sent within a try: a try succeeds with (1 - loss)^4. With
Zenoh's defaults a failed try costs a 10 s open timeout (then a back-off), so at 30 % loss a session
formed within 10 s only when its first try succeeded (24 %); with the profile's fast open (250 ms
tries retried at once) it forms in a few seconds. At 90 % no 4-datagram handshake forms in useful
time (about an hour of tries: docs/results/transports.md); there the multicast transport or the link
shim is the answer, not these settings. What is asserted is the session formed (the listener sees
its peer); the first sample is reported beside it, since it also needs the subscriber's declaration,
sent once over a UDP-only link and sometimes lost (of 24 local sessions, one sample came 10.7 s after
its session formed and one 2.2 s after; in a CI rehearsal, one session saw no sample within 15 s).
Needs root; with ZR_REQUIRE_NETNS=1 (CI) a missing capability fails the test."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import skip_unless_required

from drone_lab.experiment.netns import LossyLink, unavailable_reason

ROOT = Path(__file__).resolve().parents[2]
LOSS = 30
LIMIT_S = 10.0        # per session, from the connecting process's launch (its imports included)
SESSIONS = 3          # independent opens: the old settings pass all three with 0.24^3 = 1.4 %

SIDE = """
import dataclasses, sys, time
from drone_contract.streams import stream_profile
from zenoh_robot.session_config import open_session
role, endpoint, limit = sys.argv[1], sys.argv[2], float(sys.argv[3])
# What `--listen`/`--connect` do to the profile's session (zenoh_robot.session_args).
base = dataclasses.replace(stream_profile("resilient").session_config(), multicast_scouting=False,
                           shared_memory=False)
if role == "listen":
    session = open_session(dataclasses.replace(base, listen=[endpoint]))
    first = []
    sub = session.declare_subscriber("zr29/formed", lambda s: first.append(time.time()))
    print("READY", flush=True)
    formed = -1.0
    end = time.monotonic() + limit + 5
    while not first and time.monotonic() < end:
        if formed < 0 and list(session.info.peers_zid()):
            formed = time.time()
        time.sleep(0.01)
    if formed < 0 and first:
        formed = first[0]     # a sample came before the poll saw the peer: it had formed by then
    print(f"FORMED {formed}", flush=True)
    print(f"FIRST {first[0] if first else -1}", flush=True)
else:
    session = open_session(dataclasses.replace(base, listen=[], connect=[endpoint]))
    end = time.monotonic() + limit + 5
    while time.monotonic() < end:
        session.put("zr29/formed", b"x")
        time.sleep(0.05)
session.close()
"""


def _form_once(link: LossyLink, limit: float) -> tuple[float | None, float | None]:
    """Seconds from the connecting process's launch to the session formed (the listener sees its peer)
    and to the first sample, None for what did not happen within ``limit`` + 5 s."""
    endpoint = f"udp/{link.addr('gcs')}:7447"
    listener = subprocess.Popen(link.exec_in("gcs") + [sys.executable, "-c", SIDE, "listen", endpoint, str(limit)],
                                stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert listener.stdout is not None
    assert any(listener.stdout.readline().strip() == "READY" for _ in range(50)), "listener did not start"
    launched = time.time()
    connector = subprocess.Popen(link.exec_in("drone") + [sys.executable, "-c", SIDE, "connect", endpoint,
                                                          str(limit)], stdout=subprocess.DEVNULL, cwd=ROOT)
    try:
        out, _ = listener.communicate(timeout=limit + 30)
    finally:
        connector.kill()
        connector.wait()
    stamps = {x.split()[0]: float(x.split()[1]) for x in out.splitlines() if x.startswith(("FORMED", "FIRST"))}
    formed, first = stamps.get("FORMED", -1.0), stamps.get("FIRST", -1.0)
    return (formed - launched if formed > 0 else None), (first - launched if first > 0 else None)


@pytest.mark.netns
def test_a_unicast_session_from_the_public_api_forms_across_loss_from_startup() -> None:
    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"session-across-loss test: network namespaces are unavailable: {reason}")
    with LossyLink(loss_pct=LOSS) as link:         # lossy from the first datagram
        runs = [_form_once(link, LIMIT_S) for _ in range(SESSIONS)]
    formed = [f for f, _ in runs]
    # Asserted: the session forms (the transport, what the fast open is for). The first sample also
    # needs the subscriber's declaration to cross, which over a UDP-only link is sent once and can be
    # lost (30 % here): re-declaring until matched is open work, so it is reported, not asserted.
    print(f"\nunicast over UDP at {LOSS} % loss from start-up: formed after {formed} s, "
          f"first sample after {[d for _, d in runs]} s")
    assert all(f is not None and f <= LIMIT_S for f in formed), f"formed after (s): {runs}"
