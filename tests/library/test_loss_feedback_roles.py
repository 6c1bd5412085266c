"""Loss probes keyed by role (issue #26): a GCS's and a drone's LossMonitor never subscribe to one key.

On a lossless UDP multicast group Zenoh 1.10 bounced the declaration of the one probe key every node
subscribed to and put to (``zr_link``) between the two peers for ever, ~4,700 packets/s each way: the
8-11x bytes of the 0 % resilient cells, sealed or plain (``drone_lab.experiment.probe_storm`` counts
it). Over real multicast sessions: the two roles' probe keys are disjoint, each hears the other, the
estimate on a clean link is ~0 sealed as plain, and a deadline publisher adapted from it uses the
same copies sealed as plain (the seal costs 33 bytes a copy, never more copies).
"""
from __future__ import annotations

import math
import random
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from conftest import free_port

from drone_contract.messages import DroneSetpoint
from drone_contract.streams import PROFILES
from zenoh_robot import Node, SessionConfig
from zenoh_robot.keyring import Keyring
from zenoh_robot.loss_feedback import LossMonitor, apply_repeat_plan, probe_topics
from zenoh_robot.tools import keys
from zenoh_robot.wire import ENVELOPE, sealed
from zenoh_robot.wire.format import WireFormat

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fleet")
    keys.make_link_keys(d, gcs={"gcs1": ["uav1"]})
    return d / keys.LINK_DIR


def test_probe_topics_of_the_two_roles_are_crossed_and_disjoint() -> None:
    gcs_put, gcs_hear = probe_topics("gcs")
    drone_put, drone_hear = probe_topics("drone")
    assert gcs_put == drone_hear and drone_put == gcs_hear and gcs_hear != drone_hear
    with pytest.raises(ValueError, match="role"):
        probe_topics("router")


@contextmanager
def _pair(fleet: Path, seal: bool) -> Iterator[tuple[Node, Node, LossMonitor, LossMonitor]]:
    group = f"239.255.74.{random.randint(100, 250)}:{free_port()}"

    def wire(name: str) -> WireFormat:
        return sealed(ENVELOPE, Keyring(fleet, name)) if seal else ENVELOPE
    with Node("companion", namespace="uav1", config=SessionConfig.resilient("lo", group), wire=wire("uav1")) as drone, \
            Node("gcs", namespace="uav1", config=SessionConfig.resilient("lo", group), wire=wire("gcs1")) as gcs:
        for n in (drone, gcs):
            threading.Thread(target=n.spin, daemon=True).start()
        at_drone, at_gcs = LossMonitor(drone, "drone"), LossMonitor(gcs, "gcs")
        try:
            yield drone, gcs, at_drone, at_gcs
        finally:
            at_drone.close()
            at_gcs.close()


@pytest.mark.parametrize("seal", [False, True], ids=["plain", "sealed"])
def test_monitors_of_two_roles_hear_each_other_on_disjoint_keys_and_size_the_same_copies(fleet: Path,
                                                                                        seal: bool) -> None:
    with _pair(fleet, seal) as (drone, gcs, at_drone, at_gcs):
        # What each declared on Zenoh: no key subscribed by both (the ping-pong needs one).
        assert at_gcs._sub.data_key != at_drone._sub.data_key
        assert at_gcs._pub.data_key == at_drone._sub.data_key and at_drone._pub.data_key == at_gcs._sub.data_key
        setpoint_pub = gcs.create_publisher(DroneSetpoint, "setpoint", PROFILES["resilient"].qos["setpoint"])
        assert setpoint_pub.repeats == 64       # the profile's ceiling until the first report
        at_gcs.adapt(lambda loss: apply_repeat_plan(setpoint_pub, loss))

        def settled() -> bool:     # 2 s of probes heard each way (younger estimates say 0 by default)
            if min(at_gcs.probes_received, at_drone.probes_received) < 40:
                return False
            losses = [m.outgoing_loss() for m in (at_gcs, at_drone)]
            return all(math.isfinite(x) and x < 0.1 for x in losses) and setpoint_pub.repeats == 16
        assert gcs.spin_until(settled, 10.0), (at_gcs.probes_received, at_drone.probes_received,
                                               at_gcs.outgoing_loss(), at_drone.outgoing_loss(), setpoint_pub.repeats)
        assert at_gcs.bad_probes == 0 and at_drone.bad_probes == 0
        assert abs((setpoint_pub.repeat_window or 0) - 0.4) < 1e-9
        if seal:     # every probe opened under the fleet key: none refused on either side
            for node in (gcs, drone):
                counts = node.wire.snapshot()  # type: ignore[attr-defined]
                assert counts["opened"] > 10
                assert all(counts[k] == 0 for k in ("unknown_key", "wrong_key", "bad_tag", "replayed", "malformed"))
