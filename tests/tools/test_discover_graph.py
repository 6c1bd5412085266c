"""The CLI's graph discovery (``discover_graph``, used by topic/node/service/action list, find, info and doctor):
a graph that has been quiet because no peer was reached yet is not a settled graph."""
from __future__ import annotations

import tempfile
import threading
from pathlib import Path

import pytest

from zenoh_robot import Node, SessionConfig, msgs
from zenoh_robot.tools.cli.topic import GRAPH_QUIET, discover_graph

pytestmark = pytest.mark.fast


def test_a_peer_reached_after_a_quiet_spell_is_still_discovered(ns: str) -> None:
    """`topic find` under load printed nothing (a 3-worker test run): the CLI's session had reached no peer when
    its first GRAPH_QUIET spell ended, and it took the empty graph for the whole one. The talker here connects
    only after two spells; discovery waits for a peer (up to its timeout) and then learns the talker's topic."""
    # A Unix socket of its own, not a loopback port: a port drawn at random can be one that another test's
    # leftover session still dials, and that stranger is a peer reached (seen once in a full pass).
    with tempfile.TemporaryDirectory(prefix="zr-dg-") as tmp:
        ep = f"unixsock-stream/{Path(tmp) / 'cli.sock'}"
        listen = SessionConfig(listen=[ep], multicast_scouting=False, shared_memory=False)
        connect = SessionConfig(listen=[], connect=[ep], multicast_scouting=False, shared_memory=False)
        opened = threading.Event()
        done = threading.Event()

        def talker() -> None:
            # two quiet spells of an empty graph first: discovery must not end on them
            if done.wait(2 * GRAPH_QUIET + 0.2):
                return
            with Node("talker", namespace=ns, config=connect) as node:
                node.create_publisher(msgs.String, "chatter", 10)
                opened.set()
                done.wait(15.0)
        with Node("cli", config=listen) as cli:
            t = threading.Thread(target=talker, daemon=True)
            t.start()
            try:
                discover_graph(cli, 10.0)
                assert opened.is_set(), "discovery ended before any peer was reached"
                assert f"/{ns}/chatter" in [name for name, _ in cli.get_topic_names_and_types()]
            finally:
                done.set()
                t.join(5.0)
