"""``zenoh-robot lab px4-latency``: setpoint latency GCS -> PX4, PX4's Zenoh module against MAVLink.

One run alternates the two backends (A/B, ``reps`` each) so both see the same machine load. Per rep,
this process runs the simulator (px4_link.sim's MAVLink ``Simulator``, or px4_zenoh.sim's
``ZenohSimulator`` behind a router PX4 would join) and a minimal GCS (a zenoh_robot Node with the
resilient profile's session and setpoint QoS); the companion is a real child process
(``--px4 udpin:...`` or ``--px4 zenoh:<router>``). The GCS takes control with ``offboard_start``, arms,
and streams ``DroneSetpoint``s whose x steps by ``STEP_M`` per sample, so each target names its sample.

A sample's latency is the simulator's first receipt of its target (``setpoint_arrivals``: the MAVLink
simulator's SET_POSITION_TARGET_LOCAL_NED, the Zenoh simulator's ``trajectory_setpoint`` as Zenoh
delivered it) minus the GCS's publish instant (the header stamp's, on the monotonic clock of this same
process). Only samples published once PX4 is armed in OFFBOARD count. A target the companion never
forwards, because a newer one had arrived by the time its executor got to it (the setpoint subscription
keeps the latest: a stall of the companion skips targets), has no latency of its own: it is counted as
superseded, and ``reached`` (its target or a newer one at the simulator) keeps the stall in the figures.
Raw samples go to ``latency.jsonl.gz``, the table to ``latency.md``.
"""
from __future__ import annotations

import argparse
import dataclasses
import gzip
import json
import math
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol

from drone_contract.messages import Command, CommandResult, DroneSetpoint, VehicleState
from drone_contract.streams import stream_profile
from zenoh_robot import Node
from zenoh_robot.msgs import Header

BACKENDS = ("mavlink", "zenoh")
PROFILE = "resilient"          # the companion's default stream profile
GCS_ID = "latency-gcs"
STEP_M = 0.001                 # x step per sample: far above float32's resolution at these distances
ALT_M = 2.0
WARMUP_S = 1.0                 # the simulators' estimator warm-up: arming is not what is measured
LATE_S = 1.0                   # after the window, how long stragglers may still arrive
STOP_TIMEOUT_S = 15.0


class Px4Sim(Protocol):
    """What a latency rep reads of either simulator."""
    @property
    def mode(self) -> str: ...
    @property
    def armed(self) -> bool: ...
    @property
    def setpoint_arrivals(self) -> list[tuple[float, tuple[float, float, float] | None]]: ...


@dataclasses.dataclass
class Sample:
    backend: str
    rep: int
    k: int
    stamp_ns: int               # the DroneSetpoint's header stamp (epoch ns)
    published: float            # monotonic s at that stamp
    received: float | None = None   # monotonic s of the simulator's first receipt of target k
    reached: float | None = None    # ... of target k or a newer one

    @property
    def latency_ms(self) -> float | None:
        return None if self.received is None else (self.received - self.published) * 1e3

    @property
    def reached_ms(self) -> float | None:
        return None if self.reached is None else (self.reached - self.published) * 1e3


@dataclasses.dataclass
class Rep:
    backend: str
    rep: int
    samples: list[Sample]
    load_before: tuple[float, float, float]
    load_after: tuple[float, float, float]


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextmanager
def px4_side(backend: str) -> Iterator[tuple[Px4Sim, str]]:
    """(the running simulator, the companion's ``--px4`` value)."""
    if backend == "mavlink":
        from px4_link.sim import Simulator
        port = _free_port(socket.SOCK_DGRAM)
        with Simulator(1, port=0, target_port=port, estimator_warmup_s=WARMUP_S) as sim:
            yield sim, f"udpin:127.0.0.1:{port}"
        return
    from px4_zenoh.session import Px4Endpoint, free_tcp_endpoint, open_px4_session
    from px4_zenoh.sim import ZenohSimulator
    ep = free_tcp_endpoint()
    router = open_px4_session(Px4Endpoint("router", ep))   # the router PX4 joins; the companion is its client
    try:
        with ZenohSimulator(connect=ep, sysid=1, estimator_warmup_s=WARMUP_S) as zsim:
            yield zsim, f"zenoh:{ep}"
    finally:
        router.close()


class Gcs:
    """The GCS's part: control, offboard, arm, and the numbered setpoint stream."""

    def __init__(self, drone: str, domain: int) -> None:
        profile = stream_profile(PROFILE)
        self.endpoints = [f"tcp/127.0.0.1:{_free_port(socket.SOCK_STREAM)}",
                          f"udp/127.0.0.1:{_free_port(socket.SOCK_DGRAM)}"]
        config = dataclasses.replace(profile.session_config(), listen=self.endpoints, connect=[],
                                     multicast_scouting=False, domain=domain)
        self.node = Node("px4_latency_gcs", config=config)
        self.state: VehicleState | None = None
        self.node.create_subscription(VehicleState, f"/{drone}/state", self._on_state, profile.qos["state"])
        self.client = self.node.create_client(f"/{drone}/command", Command, CommandResult)
        self.pub = self.node.create_publisher(DroneSetpoint, f"/{drone}/setpoint", profile.qos["setpoint"])
        self.samples: dict[int, tuple[int, float]] = {}   # k -> (stamp ns, monotonic s)
        self._stop = threading.Event()
        self._spinner = threading.Thread(target=self.node.spin, name="latency-gcs", daemon=True)
        self._streamer: threading.Thread | None = None
        self._spinner.start()

    def _on_state(self, msg: VehicleState) -> None:
        self.state = msg

    def command(self, name: str) -> CommandResult:
        return self.client.call(Command(name, 0.0, "", False, GCS_ID), timeout=10.0)

    def stream(self, hz: float) -> None:
        def run() -> None:
            k, period = 0, 1.0 / hz
            due = time.monotonic()
            while not self._stop.is_set():
                k += 1
                stamp, mono = time.time_ns(), time.monotonic()
                self.samples[k] = (stamp, mono)
                self.pub.publish(DroneSetpoint(Header(stamp, "", k), GCS_ID, STEP_M * k, 0.0, -ALT_M))
                due += period
                self._stop.wait(max(0.0, due - time.monotonic()))
        self._streamer = threading.Thread(target=run, name="latency-setpoints", daemon=True)
        self._streamer.start()

    @property
    def last_k(self) -> int:
        return max(self.samples, default=0)

    def close(self) -> None:
        self._stop.set()
        if self._streamer is not None:
            self._streamer.join(timeout=2.0)
        self.node.close()


def _wait(predicate: Any, timeout: float, what: str, interval: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"px4-latency: {what} not within {timeout:g} s")
        time.sleep(interval)


def _command(gcs: Gcs, name: str, timeout: float) -> None:
    """``name`` until the companion accepts it (the first setpoints may still be on their way)."""
    deadline = time.monotonic() + timeout
    while True:
        res = gcs.command(name)
        if res.success:
            return
        if time.monotonic() > deadline:
            raise RuntimeError(f"px4-latency: {name} refused: {res.message}")
        time.sleep(0.5)


def _stop_process(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


Arrivals = list[tuple[float, tuple[float, float, float] | None]]


def first_arrivals(arrivals: Arrivals) -> dict[int, float]:
    """Sample number -> the first time its target reached the simulator."""
    first: dict[int, float] = {}
    for t, pos in sorted(arrivals, key=lambda a: a[0]):
        if pos is not None:
            first.setdefault(round(pos[0] / STEP_M), t)
    return first


def newest_arrivals(first: dict[int, float], ks: range) -> dict[int, float]:
    """Sample number -> the first time its target or a newer one reached the simulator."""
    out: dict[int, float] = {}
    soonest = math.inf
    for k in sorted((k for k in first if k >= ks.start), reverse=True):   # newest first: a running minimum
        soonest = min(soonest, first[k])
        out[k] = soonest
    for k in range(max(out, default=ks.start), ks.start - 1, -1):   # a target that never came: the next one that did
        if k not in out and k + 1 in out:
            out[k] = out[k + 1]
    return {k: out[k] for k in ks if k in out}


def run_rep(backend: str, rep: int, duration: float, hz: float, log_dir: Path) -> Rep:
    domain = 1 + secrets.randbelow(200)   # never meets another run's (or test's) system
    drone = f"lat{secrets.token_hex(3)}"
    load_before = os.getloadavg()
    with px4_side(backend) as (sim, spec):
        gcs = Gcs(drone, domain)
        log = open(log_dir / f"companion-{backend}-{rep}.log", "wb")
        cmd = [sys.executable, "-m", "companion", "--id", drone, "--px4", spec, "--camera", "none",
               "--profile", PROFILE, "--domain", str(domain)]
        for ep in gcs.endpoints:
            cmd += ["--connect", ep]
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        try:
            _wait(lambda: proc.poll() is None and gcs.state is not None and gcs.state.connected, 30,
                  "the drone's state (companion connected to PX4)")
            _wait(lambda: gcs.state is not None and gcs.state.armable, 30, "PX4 armable")
            gcs.stream(hz)
            time.sleep(0.3)
            _command(gcs, "offboard_start", 15)
            _command(gcs, "arm", 10)
            _wait(lambda: sim.armed and sim.mode == "OFFBOARD", 10, "armed in OFFBOARD")
            first_k = gcs.last_k + 1
            time.sleep(duration)
            last_k = gcs.last_k
            time.sleep(LATE_S)
            arrivals = sim.setpoint_arrivals
        finally:
            gcs.close()
            _stop_process(proc)
            log.close()
    ks = range(first_k, last_k + 1)
    first = first_arrivals(arrivals)
    reached = newest_arrivals(first, ks)
    samples = []
    for k in ks:
        stamp, mono = gcs.samples[k]
        samples.append(Sample(backend, rep, k, stamp, mono, first.get(k), reached.get(k)))
    return Rep(backend, rep, samples, load_before, os.getloadavg())


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile (``q`` in 0..100) of a non-empty list."""
    ordered = sorted(values)
    return ordered[max(0, math.ceil(q / 100 * len(ordered)) - 1)]


def summarize(reps: list[Rep]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for backend in BACKENDS:
        mine = [r for r in reps if r.backend == backend]
        if not mine:
            continue
        lat = [s.latency_ms for r in mine for s in r.samples if s.latency_ms is not None]
        newest = [s.reached_ms for r in mine for s in r.samples if s.reached_ms is not None]
        count = sum(len(r.samples) for r in mine)
        row: dict[str, Any] = {"reps": len(mine), "count": count, "delivered": len(lat),
                               "superseded": len(newest) - len(lat), "never": count - len(newest),
                               "load1": [round(r.load_before[0], 2) for r in mine]}
        if lat:
            row.update({f"p{q}": percentile(lat, q) for q in (50, 90, 99)})
            row["max"] = max(lat)
            row["min"] = min(lat)
        if newest:
            row["reached_p99"] = percentile(newest, 99)
            row["reached_max"] = max(newest)
        out[backend] = row
    return out


def _us(v: Any, digits: int = 6) -> Any:
    """Times to the µs: what the clocks resolve here, and a JSONL half the size."""
    return round(v, digits) if isinstance(v, float) else v


def _write_records(reps: list[Rep], out: Path, hz: float, duration: float) -> None:
    with gzip.open(out / "latency.jsonl.gz", "wt") as f:
        for r in reps:
            for s in r.samples:
                row = {k: _us(v) for k, v in dataclasses.asdict(s).items()}
                f.write(json.dumps({**row, "latency_ms": _us(s.latency_ms, 3), "reached_ms": _us(s.reached_ms, 3),
                                    "load1": r.load_before[0], "rate_hz": hz, "duration_s": duration}) + "\n")


def write_results(reps: list[Rep], out: Path, hz: float, duration: float,
                  records: bool = True) -> dict[str, dict[str, Any]]:
    """latency.md (and, with ``records``, the raw latency.jsonl.gz) in ``out``; the summary table."""
    out.mkdir(parents=True, exist_ok=True)
    if records:
        _write_records(reps, out, hz, duration)
    table = summarize(reps)
    lines = [
        "# Setpoint latency GCS -> PX4: PX4's Zenoh module against MAVLink",
        "",
        f"`zenoh-robot lab px4-latency --reps {max((r.rep for r in reps), default=0) + 1} "
        f"--duration {duration:g} --rate {hz:g}` ({os.cpu_count()} cores). "
        "From the GCS's publish (the DroneSetpoint's header stamp) to the simulator's first receipt of that "
        "target (MAVLink: SET_POSITION_TARGET_LOCAL_NED; Zenoh: `trajectory_setpoint`), samples published "
        "while PX4 is armed in OFFBOARD; backends alternate rep by rep. *superseded*: never forwarded, a newer "
        "target had reached the companion first (latest wins); *reached*: to the first arrival of the sample's "
        "target or a newer one (covers the superseded). Raw samples: `latency.jsonl.gz`.",
        "",
        "| backend | reps | samples | delivered | superseded | p50 ms | p90 ms | p99 ms | max ms | reached p99 ms "
        "| reached max ms | load (1 min) per rep |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for backend, row in table.items():
        cells = [f"{row[k]:.2f}" if k in row else "-" for k in ("p50", "p90", "p99", "max", "reached_p99",
                                                                 "reached_max")]
        lines.append(f"| {backend} | {row['reps']} | {row['count']} | {row['delivered']} | {row['superseded']} | "
                     f"{' | '.join(cells)} | {', '.join(f'{v:.2f}' for v in row['load1'])} |")
    lines += ["", "Per rep, in the order run:", "",
              "| rep | backend | delivered | p50 ms | p99 ms | max ms | load (1 min) |",
              "|---|---|---|---|---|---|---|"]
    for r in reps:
        lat = [s.latency_ms for s in r.samples if s.latency_ms is not None]
        cells = [f"{v:.2f}" for v in (percentile(lat, 50), percentile(lat, 99), max(lat))] if lat else ["-"] * 3
        lines.append(f"| {r.rep} | {r.backend} | {len(lat)}/{len(r.samples)} | {' | '.join(cells)} | "
                     f"{r.load_before[0]:.2f} |")
    (out / "latency.md").write_text("\n".join(lines) + "\n")
    return table


def load_results(out: Path) -> tuple[list[Rep], float, float]:
    """(reps, rate Hz, duration s) of an earlier run's ``latency.jsonl.gz``."""
    with gzip.open(out / "latency.jsonl.gz", "rt") as f:
        rows = [json.loads(line) for line in f if line.strip()]
    if not rows:
        raise ValueError(f"{out / 'latency.jsonl.gz'}: no samples")
    reps: dict[tuple[int, str], Rep] = {}
    for row in rows:
        load = (row["load1"], math.nan, math.nan)
        r = reps.setdefault((row["rep"], row["backend"]), Rep(row["backend"], row["rep"], [], load, load))
        r.samples.append(Sample(row["backend"], row["rep"], row["k"], row["stamp_ns"], row["published"],
                                row["received"], row["reached"]))
    return list(reps.values()), float(rows[0]["rate_hz"]), float(rows[0]["duration_s"])


def run_sweep(backends: list[str], reps: int, duration: float, hz: float, out: Path,
              say: Any = print) -> dict[str, dict[str, Any]]:
    done: list[Rep] = []
    log_dir = Path(tempfile.mkdtemp(prefix="zenoh-robot-px4-latency-"))
    say(f"px4-latency: {reps} rep(s) of {', '.join(backends)}, {duration:g} s at {hz:g} Hz; "
        f"companion logs in {log_dir}")
    for rep in range(reps):
        for backend in backends:   # alternating: both backends see the same load drift
            r = run_rep(backend, rep, duration, hz, log_dir)
            lat = [s.latency_ms for s in r.samples if s.latency_ms is not None]
            say(f"px4-latency: {backend} rep {rep}: {len(lat)}/{len(r.samples)} delivered, "
                f"p50 {percentile(lat, 50) if lat else math.nan:.2f} ms, load {r.load_before[0]:.2f}")
            done.append(r)
    return write_results(done, out, hz, duration)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("px4-latency", help="setpoint latency GCS -> PX4: PX4's Zenoh module against MAVLink")
    p.add_argument("--backends", default=",".join(BACKENDS), help=f"comma-separated (default {','.join(BACKENDS)})")
    p.add_argument("--reps", type=int, default=3, help="reps per backend, alternating (default 3)")
    p.add_argument("--duration", type=float, default=20.0, help="measured seconds per rep (default 20)")
    p.add_argument("--rate", type=float, default=20.0, help="setpoints per second from the GCS (default 20)")
    p.add_argument("--out", type=Path, default=Path("docs/results/px4_zenoh"),
                   help="where latency.jsonl.gz and latency.md go (default docs/results/px4_zenoh)")
    p.add_argument("--report-only", action="store_true", help="rewrite latency.md from --out's latency.jsonl.gz")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.tools.cli.main import CliError

    backends = [b for b in args.backends.split(",") if b]
    if not backends or any(b not in BACKENDS for b in backends):
        raise CliError(f"--backends: {args.backends!r}; choose from {', '.join(BACKENDS)}")
    if args.reps < 1 or not args.duration > 0 or not 0 < args.rate <= 200:
        raise CliError("--reps >= 1, --duration > 0 and --rate in (0, 200] Hz")
    if args.report_only:
        try:
            reps, hz, duration = load_results(args.out)
        except (OSError, ValueError, KeyError) as exc:
            raise CliError(f"--report-only: {exc}") from None
        # The records are what was read: rewriting them would only change the gzip header's time.
        table = write_results(reps, args.out, hz, duration, records=False)
    else:
        table = run_sweep(backends, args.reps, args.duration, args.rate, args.out)
    print(json.dumps(table))
    return 0
