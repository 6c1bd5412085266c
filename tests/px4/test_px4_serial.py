"""PX4 on a serial port, with real tty semantics: the link opens a pseudo-terminal's slave through
pyserial while the built-in simulator speaks MAVLink on the master end (tests/pty_px4.py).

Event-driven throughout: each test waits for the link's state or events, never for a time.
"""
from __future__ import annotations

import os
import random
import threading
from pathlib import Path
from typing import Any

import pytest
from conftest import wait_for
from pty_px4 import PtyWire

from px4_link import NotConnected, PositionTarget, Px4Link
from px4_link.sim import Simulator

WAIT = 10.0
# A quick take-off (only test time is at stake): motors up in 0.3 s, the climb ramp over 0.5 s, pre-arm
# checks passing 1 s after boot; the failsafe parameters are PX4's.
QUICK_FLIGHT = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.0, "COM_SPOOLUP_TIME": 0.3, "MPC_TKO_RAMP_T": 0.5}
QUICK_WARMUP_S = 1.0


class Events:
    """The link's events, waited for by name."""

    def __init__(self) -> None:
        self.seen: list[tuple[str, dict[str, Any]]] = []
        self._cond = threading.Condition()

    def __call__(self, name: str, details: dict[str, Any]) -> None:
        with self._cond:
            self.seen.append((name, details))
            self._cond.notify_all()

    def wait(self, name: str, after: int = 0, timeout: float = WAIT, **match: Any) -> dict[str, Any]:
        def found() -> dict[str, Any] | None:
            for n, d in self.seen[after:]:
                if n == name and all(d.get(k) == v for k, v in match.items()):
                    return d
            return None

        with self._cond:
            assert self._cond.wait_for(lambda: found() is not None, timeout), \
                f"no {name} {match} event; saw {[n for n, _ in self.seen]}"
            got = found()
            assert got is not None
            return got


def test_link_over_a_pty_reaches_px4_both_ways(wired: tuple[Simulator, PtyWire]) -> None:
    sim, wire = wired
    with Px4Link(wire.path) as link:
        assert link.wait_connected(WAIT)
        assert link.param.get("COM_OF_LOSS_T") == pytest.approx(1.0)   # a request out, its answer back
        assert link.stats.heartbeats_received >= 1 and link.stats.garbage_bytes == 0
        assert link.backend_summary()["connection"] == wire.path


def test_garbage_on_the_line_is_counted_and_the_link_carries_on(wired: tuple[Simulator, PtyWire]) -> None:
    _, wire = wired
    rng = random.Random(7)
    with Px4Link(f"serial://{wire.path}:57600") as link:
        assert link.wait_connected(WAIT)
        for _ in range(30):   # between (and into) the simulator's frames, as a noisy UART gives them
            wire.inject(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64))))
        assert link.wait_until(lambda: link.stats.garbage_bytes > 0, WAIT)
        beats = link.stats.heartbeats_received
        assert link.wait_until(lambda: link.stats.heartbeats_received >= beats + 2, WAIT)
        assert link.connected
        assert link.param.get("COM_OF_LOSS_T") == pytest.approx(1.0)
        assert link.stats.bad_frames > 0


def test_unplugged_device_is_a_state_and_an_event_and_replugging_reconnects(tmp_path: Path) -> None:
    device = tmp_path / "px4"      # what /dev/serial/by-id/... is: a link to the node of the day
    wire = PtyWire()
    device.symlink_to(wire.path)
    events = Events()
    with Simulator(1, port=0, target_port=wire.udp_port, seed=1) as sim:
        wire.attach(sim.port)
        with Px4Link(str(device), on_event=events) as link:
            assert link.wait_connected(WAIT)
            n = len(events.seen)
            wire.unplug()
            down = events.wait("disconnected", after=n)
            assert "vanished" in down["why"] or "failed" in down["why"]
            assert not link.connected
            events.wait("link_down", after=n)
            with pytest.raises(NotConnected, match=str(device)):
                link.action.arm()    # refused at once, saying why

            replugged = PtyWire(udp_port=wire.udp_port)
            try:
                fresh = tmp_path / "px4.new"
                fresh.symlink_to(replugged.path)
                os.replace(fresh, device)
                replugged.attach(sim.port)
                events.wait("link_up", after=n)
                assert events.wait("connected", after=n)["reconnect"] is True
                assert link.connected and link.stats.link_losses == 1
                assert link.param.get("COM_OF_LOSS_T") == pytest.approx(1.0)
            finally:
                replugged.close()


def test_a_device_that_is_missing_at_start_is_one_line() -> None:
    with pytest.raises(ConnectionError, match="no serial device /dev/ttyNOPE0"):
        Px4Link("/dev/ttyNOPE0").__enter__()


def test_bytes_without_a_frame_name_the_baud(wired: tuple[Simulator, PtyWire]) -> None:
    """A pty ignores the rate, so the line is made to look as a wrong rate does: bytes, no frame.
    (The detector itself is tested on byte streams in test_px4_url.py.)"""
    sim, wire = wired
    sim.stop()   # nothing real on the line any more
    events = Events()
    rng = random.Random(3)
    with Px4Link(f"{wire.path}:57600", on_event=events) as link:
        for _ in range(100):   # 25 kB at most; the detector speaks after 2 kB without a frame
            wire.inject(bytes(rng.randrange(256) for _ in range(256)))
            if link.wait_until(lambda: link.stats.baud_mismatches > 0, 0.05):
                break
        why = events.wait("baud_mismatch")["why"]
        assert "no MAVLink frame parses at 57600: try 921600" in why
        with pytest.raises(NotConnected, match="try 921600"):
            link.action.arm()


def test_unplugged_in_the_air_px4_holds_and_nothing_resumes_by_itself(tmp_path: Path) -> None:
    """The wire lost in OFFBOARD: PX4 stops hearing setpoints and its own offboard-loss failsafe acts
    (COM_OBL_RC_ACT = 5, Hold, as docs/hardware.md advises for a serial link); when the wire returns the
    link reports PX4 out of OFFBOARD (``offboard_lost``, on which the companion ends its session) and
    sends nothing that would put PX4 back: the vehicle holds where it was, resuming is the operator's."""
    device = tmp_path / "px4"
    wire = PtyWire()
    device.symlink_to(wire.path)
    events = Events()
    with Simulator(1, port=0, target_port=wire.udp_port, params={**QUICK_FLIGHT, "COM_OBL_RC_ACT": 5},
                   estimator_warmup_s=QUICK_WARMUP_S) as sim:
        wire.attach(sim.port)
        with Px4Link(str(device), on_event=events) as link:
            assert link.wait_connected(WAIT)
            link.offboard.set_setpoint(PositionTarget(0, 0, -3, yaw=0.0))
            link.offboard.start()
            assert wait_for(lambda: sim.armable, WAIT)
            link.action.arm()
            assert wait_for(lambda: sim.altitude > 1.5, 20)
            n = len(events.seen)
            wire.unplug()
            assert wait_for(lambda: sim.mode != "OFFBOARD", WAIT), "PX4's offboard-loss failsafe never acted"
            failsafe_mode = sim.mode
            assert failsafe_mode == "AUTO.LOITER"
            held_at = sim.altitude

            replugged = PtyWire(udp_port=wire.udp_port)
            try:
                fresh = tmp_path / "px4.new"
                fresh.symlink_to(replugged.path)
                os.replace(fresh, device)
                replugged.attach(sim.port)
                events.wait("connected", after=n, reconnect=True)
                assert events.wait("offboard_lost", after=n)["new_mode"] == failsafe_mode
                beats = link.stats.heartbeats_received
                assert link.wait_until(lambda: link.stats.heartbeats_received >= beats + 2, WAIT)
                assert sim.mode == "AUTO.LOITER" and sim.armed
                assert abs(sim.altitude - held_at) < 1.0, (held_at, sim.altitude)
            finally:
                replugged.close()
