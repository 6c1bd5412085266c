"""A raw zenoh-python client of PX4's zenoh module, as the traces' Python programs were: a router, a
client session recording every ``/fmu/out`` sample and every ``@ros2_lv`` token, keys learnt from
PX4's tokens, commands and setpoints put as PX4 expects. Used by the simulator's tests only."""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import zenoh
from conftest import free_port

from px4_zenoh.uorb import UorbCodec, load_types
from zenoh_robot.wire.ros2 import pack_attachment, parse_any_token

TYPES = load_types()
CODECS = {n: UorbCodec.of(c) for n, c in TYPES.items()}
OUT_TYPES = {"vehicle_status": "VehicleStatus", "vehicle_command_ack": "VehicleCommandAck",
             "failsafe_flags": "FailsafeFlags", "vehicle_land_detected": "VehicleLandDetected",
             "vehicle_local_position": "VehicleLocalPosition", "vehicle_control_mode": "VehicleControlMode"}


def _conf(mode: str, key: str, endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", f'"{mode}"')
    c.insert_json5(key, f'["{endpoint}"]')
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


def client_session(endpoint: str) -> zenoh.Session:
    """A Zenoh client of the router at ``endpoint``, no scouting (PX4's side, or a component of PX4's)."""
    return zenoh.open(_conf("client", "connect/endpoints", endpoint))


@dataclass
class Rec:
    t: float
    topic: str
    key: str
    payload: bytes
    attachment: bytes | None

    def decode(self) -> Any:
        return CODECS[OUT_TYPES[self.topic]].decode(self.payload)


class Probe:
    """Router on ``endpoint`` plus the recording client."""

    def __init__(self, endpoint: str | None = None) -> None:
        self.endpoint = endpoint or f"tcp/127.0.0.1:{free_port()}"
        self.router = zenoh.open(_conf("router", "listen/endpoints", self.endpoint))
        self.session = client_session(self.endpoint)
        self.recs: list[Rec] = []
        self.tokens: dict[str, float] = {}
        self._lock = threading.Lock()
        self._sub = self.session.declare_subscriber("*/fmu/out/**", self._on_sample)
        self._lv = self.session.liveliness().declare_subscriber("@ros2_lv/**", self._on_token, history=True)
        self._pubs: dict[str, Any] = {}
        self._keys: dict[str, str] = {}
        self._seq: dict[str, int] = {}
        self._stream: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self.stream_count = 0

    def _on_sample(self, s: zenoh.Sample) -> None:
        key = str(s.key_expr)
        rec = Rec(time.monotonic(), key.split("/")[3], key, s.payload.to_bytes(),
                  s.attachment.to_bytes() if s.attachment is not None else None)
        with self._lock:
            self.recs.append(rec)

    def _on_token(self, s: zenoh.Sample) -> None:
        if s.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self.tokens.setdefault(str(s.key_expr), time.monotonic())

    def close(self) -> None:
        self.stop_stream()
        self.session.close()
        self.router.close()

    # ---------------------------------------------------------------- reading
    def records(self, topic: str, since: float = 0.0) -> list[Rec]:
        with self._lock:
            return [r for r in self.recs if r.topic == topic and r.t >= since]

    def latest(self, topic: str) -> Any:
        recs = self.records(topic)
        return recs[-1].decode() if recs else None

    def wait(self, topic: str, pred: Any, timeout: float, since: float = 0.0) -> tuple[float, Any] | None:
        """(receive time, message) of the first ``topic`` sample after ``since`` with ``pred(msg)``."""
        deadline = time.monotonic() + timeout
        seen = 0
        while True:
            recs = self.records(topic, since)
            for r in recs[seen:]:
                m = r.decode()
                if pred(m):
                    return r.t, m
            seen = len(recs)
            if time.monotonic() > deadline:
                return None
            time.sleep(0.01)

    def in_key(self, topic: str) -> str:
        """The key of PX4's ``/fmu/in/<topic>``, from its MS token (never hard-coded)."""
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            with self._lock:
                toks = list(self.tokens)
            for k in toks:
                tok = parse_any_token(k)
                if tok.kind == "MS" and tok.name == f"/fmu/in/{topic}":
                    return f"{tok.domain_id}/fmu/in/{topic}/{tok.raw_type}/{tok.type_hash}"
            time.sleep(0.02)
        raise AssertionError(f"PX4 announced no subscriber for /fmu/in/{topic}")

    # ---------------------------------------------------------------- sending
    def put(self, topic: str, payload: bytes, attachment: bool = True) -> None:
        key = self._keys.get(topic) or self._keys.setdefault(topic, self.in_key(topic))
        if key not in self._pubs:
            self._pubs[key] = self.session.declare_publisher(key)
        self._seq[key] = self._seq.get(key, 0) + 1
        att = pack_attachment(self._seq[key], time.time_ns(), b"\x01" * 16) if attachment else None
        self._pubs[key].put(payload, attachment=att)

    def command(self, command: int, *params: float, target_system: int = 1, target_component: int = 1,
                source_system: int = 1, source_component: int = 1, extra: bytes = b"",
                attachment: bool = True) -> float:
        p = list(params) + [0.0] * (7 - len(params))
        msg = TYPES["VehicleCommand"](timestamp=0, param1=p[0], param2=p[1], param3=p[2], param4=p[3], param5=p[4],
                                      param6=p[5], param7=p[6], command=command, target_system=target_system,
                                      target_component=target_component, source_system=source_system,
                                      source_component=source_component, from_external=True)
        t = time.monotonic()
        self.put("vehicle_command", CODECS["VehicleCommand"].encode(msg) + extra, attachment)
        return t

    def ack(self, command: int, since: float, timeout: float = 2.0) -> tuple[float, Any] | None:
        return self.wait("vehicle_command_ack", lambda m: m.command == command, timeout, since)

    def start_stream(self, position: tuple[float, float, float], yaw: float = 0.0, hz: float = 20.0,
                     attachment: bool = True) -> None:
        self.target = position
        nan = math.nan
        self._stream_stop.clear()

        def run() -> None:
            while not self._stream_stop.is_set():
                ocm = TYPES["OffboardControlMode"](timestamp=0, position=True)
                traj = TYPES["TrajectorySetpoint"](timestamp=0, position=list(self.target), velocity=[nan] * 3,
                                                   acceleration=[nan] * 3, jerk=[nan] * 3, yaw=yaw, yawspeed=nan)
                self.put("offboard_control_mode", CODECS["OffboardControlMode"].encode(ocm), attachment)
                self.put("trajectory_setpoint", CODECS["TrajectorySetpoint"].encode(traj), attachment)
                self.stream_count += 1
                self.last_stream = time.monotonic()
                self._stream_stop.wait(1.0 / hz)
        self._stream = threading.Thread(target=run, daemon=True)
        self._stream.start()

    def stop_stream(self) -> float:
        self._stream_stop.set()
        if self._stream is not None:
            self._stream.join(2.0)
            self._stream = None
        return getattr(self, "last_stream", time.monotonic())


@contextmanager
def probed_sim(ready: bool = True, **sim_kwargs: Any) -> Iterator[tuple[Probe, Any]]:
    """A router, a Probe client and a ZenohSimulator joined to it; with ``ready``, once PX4's
    pre-flight checks pass. The simulator must end without an internal error."""
    from px4_zenoh.sim import ZenohSimulator

    probe = Probe()
    sim = ZenohSimulator(probe.endpoint, **sim_kwargs).start()
    try:
        assert sim.wait_connected(10.0)
        if ready:
            assert probe.wait("vehicle_status", lambda m: m.pre_flight_checks_pass, 10.0) is not None
        yield probe, sim
    finally:
        sim.stop()
        probe.close()
    assert not sim.internal_errors


class Hover:
    """An external-mode component's own setpoint loop (tests/px4/test_px4_zenoh_external_mode*.py): holds
    ``target`` (NED, default 3 m above home) while the mode is active."""

    def __init__(self, mode: Any, target: tuple[float, float, float] = (0.0, 0.0, -3.0)) -> None:
        self.mode, self.target = mode, target
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.mode.active:
                self.mode.trajectory(self.target, yaw=0.0)
            self._stop.wait(0.05)

    def stop(self) -> None:
        self._stop.set()
        self._th.join(1.0)
