"""The bag tests' live publisher: ``bag_talker`` (a fixture, re-exported by conftest) and the session
config file that reaches it."""
from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import linked_configs

from drone_contract.messages import VehicleState
from zenoh_robot import Node, SessionConfig, msgs, qos


class Talker:
    """Setpoints (position targets) and VehicleStates at ~50 Hz on a thread, until stopped."""

    def __init__(self, node: Node) -> None:
        # RESILIENT: each sample sent 4 times and carried again by the next ones; the JSON keeps it once
        self.sp = node.create_publisher(msgs.Setpoint, "setpoint", qos.RESILIENT)
        self.st = node.create_publisher(VehicleState, "state")
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        i = 0
        while not self.stop.is_set():
            self.sp.publish(msgs.Setpoint(msgs.Header.now(seq=i), x=float(i), y=1.0, z=-2.0))
            self.st.publish(VehicleState(msgs.Header.now(), mode="OFFBOARD", armed=True,
                                         position=[float(i) * 0.1, 0.5, -3.0]))
            i += 1
            time.sleep(0.02)


@pytest.fixture
def bag_talker(ns: str, tmp_path: Path) -> Iterator[tuple[Node, Talker, Path]]:
    """A publishing talker node in namespace ``ns`` and a session config file (JSON5) that reaches it."""
    listen, connect = linked_configs()
    cfg = tmp_path / "connect.json5"
    cfg.write_text(json.dumps(connect.to_json5()))
    with Node("talker", namespace=ns, config=listen) as node:
        t = Talker(node)
        t.thread.start()
        try:
            yield node, t, cfg
        finally:
            t.stop.set()
            t.thread.join()


def cfg_session(cfg: Path) -> SessionConfig:
    """The session config a JSON5 file holds."""
    return SessionConfig.from_file(cfg)
