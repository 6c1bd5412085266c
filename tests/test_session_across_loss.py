"""The product carries what the experiment found (issue #29): a unicast session opened through the
public API (``stream_profile("resilient").session_config()`` with the endpoints a user passes) forms
across a lossy link from start-up, as the experiment's own tuned cells did.

A UDP link between two network namespaces with loss on from the first datagram. Zenoh 1.10's
unicast open is four datagrams, never re-sent within a try: a try succeeds with (1 - loss)^4. With
Zenoh's defaults a failed try costs a 10 s open timeout (then a back-off), so at 30 % loss a session
formed within 10 s only when its first try succeeded (24 %); with the profile's fast open (250 ms
tries retried at once) it forms in a few seconds. At 90 % no 4-datagram handshake forms in useful
time (about an hour of tries: docs/results/transports.md); there the multicast transport or the link
shim is the answer, not these settings. Needs root; with ZR_REQUIRE_NETNS=1 (CI) a missing capability
fails the test."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import skip_unless_required

from drone_lab.experiment.netns import LossyLink, unavailable_reason

ROOT = Path(__file__).resolve().parents[1]
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
    end = time.monotonic() + limit + 5
    while not first and time.monotonic() < end:
        time.sleep(0.01)
    print(f"FIRST {first[0] if first else -1}", flush=True)
else:
    session = open_session(dataclasses.replace(base, listen=[], connect=[endpoint]))
    end = time.monotonic() + limit + 5
    while time.monotonic() < end:
        session.put("zr29/formed", b"x")
        time.sleep(0.05)
session.close()
"""


def _form_once(link: LossyLink, limit: float) -> float | None:
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
    first = float(next(x for x in out.splitlines() if x.startswith("FIRST")).split()[1])
    return first - launched if first > 0 else None


@pytest.mark.netns
def test_a_unicast_session_from_the_public_api_forms_across_loss_from_startup() -> None:
    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"session-across-loss test: network namespaces are unavailable: {reason}")
    with LossyLink(loss_pct=LOSS) as link:         # lossy from the first datagram
        formed = [_form_once(link, LIMIT_S) for _ in range(SESSIONS)]
    assert all(f is not None and f <= LIMIT_S for f in formed), f"formed after (s): {formed}"
