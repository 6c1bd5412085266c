"""A flight controller on a serial port, for tests: a pseudo-terminal whose master end carries the
built-in simulator's MAVLink, so the link opens a real tty (pyserial, termios, EOF on hang-up).

``PtyWire(sim_port)`` bridges a new pty's master to the simulator's UDP socket; ``wire.path`` is the
slave, the "device". ``wire.unplug()`` hangs the tty up as a pulled USB cable does; ``wire.inject``
puts bytes on the line between the simulator's frames. The ``wired`` fixture (a simulator behind a
fresh wire) is visible to every test module (conftest's ``pytest_plugins``).
"""
from __future__ import annotations

import os
import select
import socket
import threading
import tty
from collections.abc import Iterator
from typing import Any

import pytest


class PtyWire:
    def __init__(self, udp_port: int = 0) -> None:
        """``udp_port``: a replugged wire takes its predecessor's, where the simulator still sends."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", udp_port))
        self.udp_port: int = self.sock.getsockname()[1]   # the simulator's target_port
        self.sim_port: int | None = None                  # where the simulator listens (set by attach)
        self.master, self._slave = os.openpty()
        # Raw before anyone opens it: a cooked slave would echo the simulator's bytes back to it.
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.to_link = 0
        self.from_link = 0
        self._thread = threading.Thread(target=self._run, name="pty-wire", daemon=True)

    def attach(self, sim_port: int) -> PtyWire:
        self.sim_port = sim_port
        self._thread.start()
        return self

    def inject(self, data: bytes) -> None:
        with self._lock:
            os.write(self.master, data)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.master, self.sock], [], [], 0.05)
            except (OSError, ValueError):
                return
            if self.sock in ready:
                data = self.sock.recv(65535)
                with self._lock:
                    try:
                        os.write(self.master, data)
                    except OSError:
                        return
                self.to_link += len(data)
            if self.master in ready:
                try:
                    data = os.read(self.master, 4096)
                except OSError:   # EIO: nobody holds the slave (between opens): nothing to forward
                    self._stop.wait(0.01)
                    continue
                if data and self.sim_port is not None:
                    self.sock.sendto(data, ("127.0.0.1", self.sim_port))
                    self.from_link += len(data)

    def unplug(self) -> None:
        """The cable pulled: the master closes, every open slave sees the hang-up."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self.sock.close()

    close = unplug


@pytest.fixture
def wired() -> Iterator[tuple[Any, PtyWire]]:
    """The built-in simulator (system 1) behind a fresh pty: (simulator, wire)."""
    from px4_link.sim import Simulator

    wire = PtyWire()
    with Simulator(1, port=0, target_port=wire.udp_port, seed=1) as sim:
        wire.attach(sim.port)
        yield sim, wire
    wire.close()
