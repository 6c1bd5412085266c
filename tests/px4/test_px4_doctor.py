"""``zenoh-robot doctor --px4 DEVICE`` (issue #38): the flight controller's port checked from the doctor,
over a real tty (tests/pty_px4.py: the built-in simulator's MAVLink on a pseudo-terminal)."""
from __future__ import annotations

import os
import random
import threading

from cli_helpers import cli
from pty_px4 import PtyWire

from px4_link.sim import Simulator

DOCTOR = ("doctor", "--no-clock", "--timeout", "0.3")


def _line(out: str, name: str) -> str:
    return next((ln for ln in out.splitlines() if f" {name}: " in ln), f"<no {name} line>")


def test_a_reachable_flight_controller_is_named_with_its_system() -> None:
    wire = PtyWire()
    try:
        with Simulator(3, port=0, target_port=wire.udp_port, seed=1) as sim:
            wire.attach(sim.port)
            run = cli(*DOCTOR, "--px4", f"{wire.path}:921600")
    finally:
        wire.close()
    device, link = _line(run.stdout, "px4 device"), _line(run.stdout, "px4 link")
    assert device.startswith("OK") and wire.path in device, run.stdout
    assert link.startswith("OK") and "heartbeats from system 3" in link and "921600 baud" in link, run.stdout
    # The simulator answers MAV_CMD_REQUEST_MESSAGE 148 with flight_sw_version 1.15.0, official.
    assert _line(run.stdout, "px4 firmware").startswith("OK") and "PX4 v1.15.0 (official)" in run.stdout, run.stdout
    # AVAILABLE_MODES over the tty: PX4's 26 (18 selectable, TERMINATION not), its 8 external slots free.
    modes = _line(run.stdout, "px4 modes")
    assert modes.startswith("OK") and "26 modes, 17 selectable: MANUAL, ALTCTL, POSCTL" in modes, run.stdout
    assert "TERMINATION" not in modes and "8 external slots free" in modes, run.stdout
    assert "Traceback" not in run.stderr


def test_firmware_version_reads_as_px4_writes_it() -> None:
    from px4_link.link import describe_version
    # PX4's version.c: major, minor, patch, type; its git hash's first 16 hex digits as a little-endian uint64.
    git = bytes.fromhex("1a2b3c4d5e6f7081")[::-1]
    assert describe_version(0x0111_0000, git) == "v1.17.0 (dev), git 1a2b3c4d5e6f7081"
    assert describe_version(0x010F_02C0, bytes(8)) == "v1.15.2 (rc)"
    assert describe_version(0x010F_00FF, bytes(8)) == "v1.15.0 (official)"


def test_a_missing_device_and_a_wrong_form_fail_in_one_line() -> None:
    run = cli(*DOCTOR, "--px4", "/dev/ttyNOPE0")
    assert run.returncode == 1 and _line(run.stdout, "px4 device").startswith("FAIL")
    assert "no serial device /dev/ttyNOPE0" in run.stdout and "Traceback" not in run.stderr
    run = cli(*DOCTOR, "--px4", "foo")
    assert run.returncode == 1 and "is not a PX4 connection" in _line(run.stdout, "px4")


def test_bytes_that_never_parse_name_the_baud_to_try() -> None:
    """A port at the wrong rate delivers bytes in which no MAVLink frame parses: the check says so and
    which rate to try, rather than "no heartbeat"."""
    wire = PtyWire()
    stop = threading.Event()
    rng = random.Random(3)

    def noise() -> None:   # what a UART at the wrong rate reads: bytes, never a frame
        while not stop.is_set():
            try:
                wire.inject(bytes(rng.randrange(256) for _ in range(256)).replace(b"\xfd", b"").replace(b"\xfe", b""))
            except OSError:
                return
            stop.wait(0.01)
    feeder = threading.Thread(target=noise, daemon=True)
    feeder.start()
    try:
        run = cli(*DOCTOR, "--px4", f"{wire.path}:57600")
    finally:
        stop.set()
        feeder.join(2.0)
        wire.close()
    link = _line(run.stdout, "px4 link")
    assert run.returncode == 1 and link.startswith("FAIL"), run.stdout
    assert "no MAVLink frame parses at 57600: try 921600" in link, run.stdout
    assert os.path.basename(wire.path) in link
