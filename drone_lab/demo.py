"""``zenoh-robot demo``: the whole system on localhost, flying a square, with live statistics.

Three processes, as on a drone: the PX4 simulator, the companion (MAVLink <-> Zenoh)
and the GCS (mission + dashboard in this terminal). At the end, one summary joins
both ends' records: delivered %, age and period per stream, and how far the vehicle
strayed from the path.

``--duration`` is the whole run, take-off and landing included: at that time the GCS is
asked to stop. Ctrl-C reaches only this process (each child has its own session), which
then stops the others in dependency order: the GCS first (it writes its record), then
the companion (it still has PX4 to command HOLD), then the simulator; so the summary is
printed after an interrupted run too.
"""
from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from zenoh_robot.tools.stream_metrics import StreamRecorder, analyse


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("demo", help="run simulator + companion + GCS on localhost and fly a square")
    p.add_argument("--duration", type=float, default=60.0,
                   help="seconds for the whole run, take-off and landing included (default 60)")
    p.add_argument("--pattern", default="square", choices=("square", "circle", "line", "hover"))
    p.add_argument("--profile", default="resilient", help="stream profile (default resilient)")
    p.add_argument("--drone", default="uav1")
    p.add_argument("--px4", choices=("mavlink", "zenoh"), default="mavlink",
                   help="how the companion talks to PX4: mavlink (the MAVLink simulator, default) or zenoh (PX4's "
                        "Zenoh protocol, no MAVLink: `python -m px4_zenoh.sim` joins the companion's router on "
                        "PX4 SITL's tcp/127.0.0.1:7447)")
    p.set_defaults(func=run)


PX4_ZENOH_ENDPOINT = ("127.0.0.1", 7447)   # PX4 SITL's default router locator (zenoh/net.txt)


def _tcp_port_free(addr: tuple[str, int]) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(addr)
        except OSError:
            return False
        return True


def _px4_processes(args: argparse.Namespace, py: str, port: int, console: Console) -> tuple[list[str], list[str]]:
    """(simulator command or [], the companion's --px4 value) for ``--px4``."""
    if args.px4 == "mavlink":
        return [py, "-m", "px4_link.sim", "--port", "0", "--target-port", str(port)], [f"udpin:127.0.0.1:{port}"]
    if _tcp_port_free(PX4_ZENOH_ENDPOINT):
        # as on a drone: the companion's embedded router on PX4's locator, the simulated PX4 a client of it
        host, tcp = PX4_ZENOH_ENDPOINT
        return [py, "-m", "px4_zenoh.sim", "--connect", f"tcp/{host}:{tcp}"], ["zenoh"]
    # the companion cannot listen on another port yet: the simulator runs inside it on a free one
    console.print("demo: tcp/127.0.0.1:7447 is taken (a zenohd?); the Zenoh simulator runs inside the companion")
    return [], ["zenoh-sim"]


def _wait_listening(addr: tuple[str, int], proc: subprocess.Popen[bytes], deadline: float) -> None:
    """Until something accepts TCP connections on ``addr`` (or ``proc`` ended, or ``deadline``)."""
    while time.monotonic() < deadline and proc.poll() is None:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex(addr) == 0:
                return
        time.sleep(0.1)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


# s of a run that are not the pattern: start-up and take-off (~11 s), landing to disarm (~13 s, as
# PX4 SITL lands), and a margin; the simulator keeps PX4's timings, so a shorter budget cuts the landing.
SETUP_S = 30.0
MIN_DURATION_S = SETUP_S + 10.0
# A slow start (a loaded machine: 35 s to start was seen) must not cut a healthy flight short: past its
# planned end the demo lets the mission land, this much longer at most, and says so.
OVERTIME_S = 90.0
STOP_TIMEOUT = 15.0    # s a child has to stop after SIGINT (the GCS lands and writes its record)


def _stop(proc: subprocess.Popen[bytes], name: str, console: Console) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            console.print(f"demo: {name} did not stop in {STOP_TIMEOUT:g} s; killing it")
            proc.kill()
            proc.wait()


def _wait_until(proc: subprocess.Popen[bytes], deadline: float) -> bool:
    """True when ``proc`` ended before ``deadline``."""
    while proc.poll() is None:
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        try:
            proc.wait(timeout=min(left, 0.5))
        except subprocess.TimeoutExpired:
            pass
    return True


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.tools.cli.main import CliError

    if not args.duration >= MIN_DURATION_S:
        raise CliError(f"--duration must be at least {MIN_DURATION_S:g} s (take-off and landing alone take "
                       f"about {SETUP_S:g} s), got {args.duration:g}")
    console = Console()
    _hangup_is_interrupt()
    started = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="zenoh-robot-demo-"))
    port = _free_udp_port()
    py = sys.executable
    logs = {name: open(work / f"{name}.log", "w") for name in ("sim", "companion")}
    console.print(f"demo: simulator, companion and GCS on localhost for {args.duration:g} s; logs in {work}")
    # Every child in its own session: a terminal's Ctrl-C reaches this process only, which stops the rest in order.
    sim_cmd, px4_spec = _px4_processes(args, py, port, console)
    companion = subprocess.Popen([py, "-m", "companion", "--id", args.drone, "--px4", *px4_spec,
                                  "--profile", args.profile, "--record", str(work / "companion.json"),
                                  "--ros2-topics"],   # the drone as standard ROS 2 types too (docs/ros2.md)
                                 stdout=logs["companion"], stderr=subprocess.STDOUT, start_new_session=True)
    # after the companion: a Zenoh PX4 is a client of the companion's router and retries every 5 s, as PX4
    # does; started once the router listens, the simulated PX4 joins at its first try
    if px4_spec == ["zenoh"]:
        _wait_listening(PX4_ZENOH_ENDPOINT, companion, time.monotonic() + 15.0)
    sim = subprocess.Popen(sim_cmd or [py, "-c", "pass"], stdout=logs["sim"], stderr=subprocess.STDOUT,
                           start_new_session=True)
    pattern_s = args.duration - SETUP_S   # so the GCS lands and ends by itself before the deadline
    gcs_cmd = [py, "-m", "gcs", "--drones", args.drone, "--mission", "--duration", f"{pattern_s:g}",
               "--pattern", args.pattern, "--profile", args.profile, "--record", str(work / "gcs.json")]
    from zenoh_robot.tools.foxglove_bridge import pick_port
    fox_port = pick_port(8765)
    gcs_cmd += ["--foxglove", str(fox_port)]
    flight_log = work / "flight.mcap"   # every topic, as it flew (zenoh-robot bag info/play; opens in Foxglove)
    logs["bag"] = open(work / "bag.log", "w")
    bag = subprocess.Popen([py, "-m", "zenoh_robot.tools.cli.main", "bag", "record", "-a", "-o", str(flight_log)],
                           stdout=logs["bag"], stderr=subprocess.STDOUT, start_new_session=True)
    gcs = subprocess.Popen(gcs_cmd, stdin=subprocess.DEVNULL, start_new_session=True)
    console.print(f"demo: live view: open Foxglove on ws://127.0.0.1:{fox_port}")
    rc = 0
    try:
        if not _wait_until(gcs, started + args.duration):
            console.print(f"demo: {args.duration:g} s are up but the mission is still flying (a slow start); "
                          f"letting it land, {OVERTIME_S:g} s more at most (Ctrl-C stops it now)")
            if not _wait_until(gcs, started + args.duration + OVERTIME_S):
                console.print("demo: the mission did not end in time; stopping it (the drone holds, then the "
                              "companion stops)")
        # The demo did its job only if the mission did: the GCS's exit code says so (1: failed or cut short).
        rc = gcs.returncode if gcs.returncode is not None else 1
    except KeyboardInterrupt:
        rc = 130
        console.print("demo: interrupted; stopping (GCS, then companion, then simulator)")
    finally:
        _stop_all([(gcs, "gcs"), (bag, "bag"), (companion, "companion"), (sim, "simulator")], console)
        for f in logs.values():
            f.close()
    for name, proc in (("simulator", sim), ("companion", companion)):
        if proc.returncode not in (0, -signal.SIGINT, 130):
            log_name = name[:3] if name == "simulator" else name
            console.print(f"demo: {name} exited with {proc.returncode}; see {work / log_name}.log")
    print_summary(console, work, args.drone)
    console.print(f"demo: flight log {flight_log} ({flight_log.stat().st_size / 1e6:.1f} MB): "
                  f"`zenoh-robot bag info {flight_log}`, or open it in Foxglove" if flight_log.exists()
                  else f"demo: no flight log (see {work / 'bag.log'})")
    console.print(f"demo: {time.monotonic() - started:.1f} s in all")
    if rc not in (0, 130):
        console.print(f"demo: the mission did not succeed (GCS exit code {rc}); see the GCS's lines above")
    return rc if rc >= 0 else 1


def _hangup_is_interrupt() -> None:
    """A closed terminal (SIGHUP) or a ``kill`` (SIGTERM) stops the demo as Ctrl-C does, in order: its
    children run in sessions of their own and would otherwise fly on, orphaned."""
    def interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    for sig in (signal.SIGHUP, signal.SIGTERM):
        signal.signal(sig, interrupt)


def _stop_all(procs: list[tuple[subprocess.Popen[bytes], str]], console: Console) -> None:
    """Dependents first: each stops (and records) while what it depends on still runs. A second
    Ctrl-C while waiting moves on to the next one rather than abandoning them all."""
    for proc, name in procs:
        try:
            _stop(proc, name, console)
        except KeyboardInterrupt:
            console.print(f"demo: killing {name}")
            proc.kill()
            proc.wait()


def print_summary(console: Console, work: Path, drone: str) -> None:
    try:
        gcs = json.loads((work / "gcs.json").read_text())["drones"][drone]
        comp = json.loads((work / "companion.json").read_text())
    except (OSError, ValueError, KeyError) as exc:
        console.print(f"demo: no summary ({exc})")
        return
    sent, recv = gcs["logs"]["sent"], gcs["logs"]["received"]
    pairs = {"setpoint ->": (comp["logs"]["received"]["setpoint"], sent["setpoint"]),
             "sensor <-": (recv["sensor"], comp["logs"]["sent"]["sensor"]),
             "state <-": (recv["state"], comp["logs"]["sent"]["state"]),
             "image <-": (recv["image"], comp["logs"]["sent"]["image"])}
    t = Table(title="demo summary (-> GCS to drone, <- drone to GCS)")
    for col in ("stream", "sent", "delivered %", "age avg ms", "age p99 ms", "period avg ms", "period max ms"):
        t.add_column(col, justify="right" if col != "stream" else "left")
    for name, (r, s) in pairs.items():
        # Over the time both ends were up: from the first to the last sample that arrived.
        stamps = r["stamp_ns"] or [0]
        a = analyse(StreamRecorder.from_dict(r), StreamRecorder.from_dict(s), min(stamps), max(stamps))
        t.add_row(name, str(a.sent), f"{a.delivered_pct:.1f}", f"{a.age_avg_ms:.1f}", f"{a.age_p99_ms:.1f}",
                  f"{a.period_avg_ms:.1f}", f"{a.period_max_ms:.1f}")
    console.print(t)
    console.print(f"largest distance from the setpoint path: {gcs['max_path_error_m']:.2f} m; "
                  f"frames shown {gcs['frames']} ({gcs['frames_complete']} whole); "
                  f"setpoints rejected by the companion: {comp['setpoints_rejected']}; "
                  f"final mode {comp['final_mode']}")
