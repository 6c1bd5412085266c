"""``zenoh-robot gcs``: stream setpoints, show the dashboard, fly a mission, send commands.

A run checks the flags into a typed ``GcsRun`` (``parse_run``: a user's mistake is one line and
exit 2, before any session opens), then ``serve`` runs it: the node, the ``Gcs`` and what runs
beside it (gcs/extras.py), the mission on its own thread, the dashboard until the mission or the
duration ends, the summary. ``gcs cmd`` goes the same way: ``parse_command``, ``send_command``.
"""
from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.live import Live

from drone_contract.commands import CLI_COMMANDS, COMMAND_SERVICE, resolve_cli_name
from drone_contract.link_protection import link_wire, log_startup_line, reaches_network
from drone_contract.messages import Command, CommandResult, valid_client_id
from drone_contract.streams import IMAGE_MODES, PROFILES, StreamProfile, stream_profile
from zenoh_robot import Node, SessionConfig
from zenoh_robot.parameters import add_param_argument, params_from_args
from zenoh_robot.services import ServiceCallError, command_retry
from zenoh_robot.session_args import add_session_arguments, session_config_from_args
from zenoh_robot.wire import ENVELOPE, WireFormat

from .app import Gcs
from .config import GcsConfig, default_client_id
from .dashboard import RateMeter, plain_lines, render
from .discovery import discover_drones
from .extras import ExtrasOptions, GcsExtras
from .formation import FORMATIONS, resolve
from .goto import parse_target, send_goto
from .mavlink_out import parse_udpout
from .mission import ON_FAILURE, run_mission, run_swarm_mission
from .patterns import PATTERNS
from .summary import print_summary, summarize, write_record

if TYPE_CHECKING:
    from zenoh_robot.keyring import Keyring

log = logging.getLogger("gcs")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("gcs", help="ground control station: setpoints, telemetry, images, commands")
    add_common(p)
    actions = p.add_subparsers(dest="gcs_action", metavar="ACTION")
    c = actions.add_parser("cmd", help="send one command to a drone, or to all: arm, takeoff 5, land, hold, ...")
    c.add_argument("drone", help="a drone id, or 'all': every drone of --drones, else every drone heard "
                                 "within --discover s")
    c.add_argument("command", choices=(*CLI_COMMANDS, "goto"))
    c.add_argument("value", nargs="?", help="takeoff altitude, NAME=VALUE for set_param, the GCS id to "
                                           "hand control over to (hand_over, release_control), or goto's "
                                           "NORTH,EAST,ALTITUDE in metres (the drone's goto action)")
    c.add_argument("--force", action="store_true",
                   help="disarm: in flight (the companion refuses unless started with --allow-force-disarm); "
                        "take_control: take over from another GCS")
    c.add_argument("--timeout", type=float, default=8.0)
    add_session_arguments(c)
    c.add_argument("--gcs-id", default=None, help="this GCS's id (default user@host, shared with `gcs` runs)")
    c.add_argument("--link-keys", metavar="DIR", default=os.environ.get("ZR_LINK_KEYS"),
                   help="seal the command with this GCS's link keyring DIR/<gcs id>.json "
                   "(needed when the companion runs with --link-keys; default $ZR_LINK_KEYS)")
    c.add_argument("--drones", help="with 'all': comma-separated drone ids (default: discover)")
    c.add_argument("--discover", type=float, default=2.0, help="with 'all' and no --drones: listen this long, s")
    p.set_defaults(func=run)


def add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--drones", help="comma-separated drone ids (default: discover)")
    p.add_argument("--pattern", choices=PATTERNS, default="thesis")
    p.add_argument("--rate", type=float, default=10.0, help="setpoint rate, Hz (default 10, as the thesis)")
    p.add_argument("--altitude", type=float, default=5.0)
    p.add_argument("--size", type=float, default=10.0, help="pattern size, m")
    p.add_argument("--speed", type=float, default=2.0, help="pattern speed, m/s")
    p.add_argument("--profile", choices=sorted(PROFILES), default="resilient", help="stream QoS/transport profile")
    p.add_argument("--iface", help="network interface towards the drones for the multicast transport "
                   "(profiles resilient, resilient_multicast; required by the latter)")
    add_session_arguments(p)
    p.add_argument("--image", choices=IMAGE_MODES, help="image path, overriding the profile's (must match the drone's)")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--mission", action="store_true",
                   help="fly every drone of --drones at once: offboard, arm, pattern for --duration, land; "
                        "without it the pattern is flown once an operator starts a drone's offboard session")
    p.add_argument("--link-keys", metavar="DIR", default=os.environ.get("ZR_LINK_KEYS"),
                   help="seal every topic sample (ChaCha20-Poly1305, replay window, per-role keys) with this "
                        "node's keyring DIR/<gcs id>.json from `zenoh-robot keys link` (docs/security.md); "
                        "re-read on SIGHUP; default $ZR_LINK_KEYS")
    p.add_argument("--link-encrypt", action="store_true", help="with --link-keys: encrypt samples too")
    p.add_argument("--insecure-ok", action="store_true",
                   help="fly --mission over a network (--iface, or --connect to another host) without --secure: "
                        "anyone who reaches that network can command the drones as this GCS")
    p.add_argument("--on-failure", choices=ON_FAILURE, default="continue",
                   help="--mission with several drones: when one fails, the others go on or hold (default continue)")
    p.add_argument("--formation", choices=FORMATIONS, default="auto",
                   help="each drone its own slot: line, grid; none: each flies from where it is; "
                        "auto (default): none for one drone, line for several")
    p.add_argument("--spacing", type=float, default=5.0, help="m between formation slots (default 5)")
    p.add_argument("--patterns", default="", metavar="ID=PATTERN,...",
                   help="per-drone patterns overriding --pattern, e.g. uav2=circle,uav3=hover")
    p.add_argument("--sensor-rate", type=float, metavar="HZ",
                   help="ask each drone, when it joins, for SensorCombined at this rate (its sensor_rate_hz; "
                        "default: the drone's own, 200 Hz). A refusal or no answer is reported and asked "
                        "again at its next join")
    p.add_argument("--camera-rate", type=float, metavar="HZ",
                   help="ask each drone, when it joins, for camera frames at this rate (its camera_rate_hz; "
                        "default: the drone's own, 30 fps)")
    p.add_argument("--keep-sensor-rate", action="store_true",
                   help="never ask a drone for less sensor when this GCS cannot keep up (default: a drone this "
                        "GCS controls is asked for the rate it kept up with, said as an alert and put back "
                        "when the GCS closes)")
    p.add_argument("--details", metavar="ID", help="dashboard: show this drone's streams as well")
    p.add_argument("--gcs-id", default=None,
                   help="this GCS's id, carried by its setpoints and commands (default user@host)")
    p.add_argument("--take-control", action="store_true",
                   help="take control of the drones from whichever GCS holds it (that GCS is told)")
    p.add_argument("--no-dashboard", action="store_true", help="log lines instead of the live table")
    p.add_argument("--record", type=Path,
                   help="FILE.mcap: record every topic as a flight log (Foxglove opens it; `zenoh-robot bag`), "
                        "summary in FILE.summary.json; or per-stream figures at the end: FILE.json (with raw "
                        "sample records) or FILE.csv (one row per stream)")
    p.add_argument("--foxglove", type=int, nargs="?", const=8765, metavar="PORT",
                   help="serve every topic live to Foxglove on ws://127.0.0.1:PORT (default 8765)")
    p.add_argument("--mavlink-out", metavar="udpout:HOST:PORT",
                   help="re-emit the drones' tunnelled MAVLink (companion --mavlink-tunnel) for QGC, "
                        "e.g. udpout:127.0.0.1:14550 (drone i on PORT+10i)")
    p.add_argument("--save-image", type=Path, help="save the latest frame here (PNG/JPEG) every --save-every s")
    p.add_argument("--save-every", type=float, default=5.0)
    p.add_argument("--no-topic-statistics", action="store_true",
                   help="do not publish per-stream statistics (what `zenoh-robot stats` shows)")
    add_param_argument(p)


def session_config(args: argparse.Namespace, profile: StreamProfile) -> SessionConfig:
    """The session of ``--zenoh`` (else the profile's) refined by the session flags."""
    from zenoh_robot.tools.cli.main import CliError

    def from_profile() -> SessionConfig:
        try:   # the profile says unicast or multicast; multicast needs --iface (one-line error otherwise)
            return profile.session_config(getattr(args, "iface", None))
        except ValueError as exc:
            raise CliError(str(exc)) from None

    return session_config_from_args(args, from_profile, "gcs")


class UsageError(Exception):
    """A user's mistake in the flags: one line, exit 2, before any session opens."""


@dataclass(frozen=True)
class GcsRun:
    """One ``gcs`` run, from its validated flags."""
    gcs: GcsConfig
    session: SessionConfig
    wire: WireFormat
    keyring: Keyring | None
    link_encrypt: bool
    params: dict[str, Any]                # -p overrides, the node's parameters
    extras: ExtrasOptions
    mission: bool
    duration: float | None
    on_failure: str
    insecure_ok: bool
    dashboard: bool                       # the live table; else (or not on a terminal) plain lines
    details: str | None
    topic_statistics: bool
    record: Path | None


def run(args: argparse.Namespace) -> int:
    if args.gcs_action == "cmd":
        return run_command(args)
    _sigterm_as_ctrl_c()
    try:
        gcs_run = parse_run(args)
        log_startup_line(log, gcs_run.session, gcs_run.keyring, gcs_run.link_encrypt)
        refuse_an_open_mission(gcs_run)
    except UsageError as exc:
        print(f"gcs: {exc}", file=sys.stderr)
        return 2
    return serve(gcs_run)


def _sigterm_as_ctrl_c() -> None:
    """SIGTERM (systemd, `kill`, a launch's second try) stops the GCS as Ctrl-C does: the mission stops as it
    is, the summary says what each drone is doing and how to land it; by default SIGTERM ends the process
    at once, silently, leaving the operator with neither."""
    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, interrupt)


def parse_run(args: argparse.Namespace) -> GcsRun:
    """The flags checked and typed; UsageError names the first that is wrong."""
    params = params_from_args(args)
    profile = stream_profile(args.profile, params, image_mode=args.image)
    client_id = _client_id(args.gcs_id)
    patterns = _patterns(args.patterns)
    drones = _drone_list(args.drones)
    _check_numbers(args)
    if args.take_control and not drones:
        raise UsageError("--take-control needs --drones (which drones to take)")
    if args.mission and not drones:
        raise UsageError("--mission needs the drones to fly (--drones uav1,uav2)")
    config = GcsConfig(drones=drones, pattern=args.pattern, rate_hz=args.rate, altitude=args.altitude,
                       size=args.size, speed=args.speed, profile=profile, save_image=args.save_image,
                       save_every=args.save_every, client_id=client_id, take_control=args.take_control,
                       auto_fly=not args.mission, formation=resolve(args.formation, len(drones) or 2),
                       spacing=args.spacing, patterns=patterns, sensor_rate_hz=args.sensor_rate,
                       decimate_sensor=not args.keep_sensor_rate,
                       camera_rate_hz=args.camera_rate)
    session = session_config(args, profile)
    wire, keyring = _link(args.link_keys, client_id, args.link_encrypt)
    return GcsRun(gcs=config, session=session, wire=wire, keyring=keyring,
                  link_encrypt=args.link_encrypt, params=params, extras=_extras(args), mission=args.mission,
                  duration=args.duration, on_failure=args.on_failure, insecure_ok=args.insecure_ok,
                  dashboard=not args.no_dashboard, details=args.details,
                  topic_statistics=not args.no_topic_statistics, record=args.record)


def _drone_list(spec: str | None) -> list[str]:
    drones = [d for d in (spec or "").split(",") if d]
    if len(set(drones)) != len(drones):
        raise UsageError(f"--drones names a drone twice: {spec}")
    return drones


def _client_id(gcs_id: str | None) -> str:
    cid = gcs_id or default_client_id()
    if not valid_client_id(cid):
        raise UsageError(f"--gcs-id {cid!r}: letters, digits and _.@:+- only, at most 64")
    return cid


def _patterns(spec: str) -> dict[str, str]:
    patterns = {}
    for item in (x for x in spec.split(",") if x):
        drone, sep, name = item.partition("=")
        if not sep or name not in PATTERNS:
            raise UsageError(f"--patterns {item!r}: expected ID=PATTERN, PATTERN one of {', '.join(PATTERNS)}")
        patterns[drone] = name
    return patterns


def _check_numbers(args: argparse.Namespace) -> None:
    # Each would fail later, inside the running node (a zero rate is a division by zero there).
    for flag, v, unit in (("--rate", args.rate, "Hz"), ("--size", args.size, "m"), ("--spacing", args.spacing, "m"),
                          ("--save-every", args.save_every, "s"), ("--sensor-rate", args.sensor_rate, "Hz"),
                          ("--camera-rate", args.camera_rate, "Hz")):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UsageError(f"{flag} must be > 0 {unit}, got {v!r}")


def _link(keys_dir: str | None, client_id: str, encrypt: bool) -> tuple[WireFormat, Keyring | None]:
    """The wire format and keyring of ``--link-keys``: this GCS id's key is what "the GCS in control" means."""
    if not keys_dir:
        return ENVELOPE, None
    try:
        return link_wire(keys_dir, client_id, encrypt=encrypt)
    except ValueError as exc:
        raise UsageError(f"--link-keys: {exc}") from None


def _extras(args: argparse.Namespace) -> ExtrasOptions:
    try:
        mavlink_out = parse_udpout(args.mavlink_out) if args.mavlink_out else None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return ExtrasOptions(record=args.record, foxglove_port=args.foxglove, mavlink_out=mavlink_out)


def refuse_an_open_mission(gcs_run: GcsRun) -> None:
    # One flag must not be all that stands between a field flight and an open link.
    if gcs_run.mission and not (gcs_run.session.secure or gcs_run.keyring) and reaches_network(gcs_run.session) \
            and not gcs_run.insecure_ok:
        raise UsageError("--mission over a network without --secure: commands would be unauthenticated (a peer can "
                         "claim this GCS's client id); give --secure DIR or --link-keys DIR, or --insecure-ok to fly "
                         "anyway")


def serve(gcs_run: GcsRun) -> int:
    """Opens the node, runs the GCS (and a mission) until it ends, prints and writes the summary."""
    console = Console(stderr=False)
    config = gcs_run.gcs
    if config.save_image and len(config.drones) != 1:
        path = config.save_image
        console.print(f"gcs: --save-image: one file per drone, {path.with_name(path.stem + '_<id>' + path.suffix)} "
                      "(each name is printed when first written)")
    result: dict[str, Any] = {}
    with Node("gcs", config=gcs_run.session, parameter_overrides=gcs_run.params, wire=gcs_run.wire,
              enable_topic_statistics=gcs_run.topic_statistics) as node:
        gcs = Gcs(node, config)
        extras = GcsExtras(node, gcs_run.extras, config.drones, console.print)
        spinner = threading.Thread(target=node.spin, name="gcs-spin", daemon=True)
        spinner.start()
        if config.take_control:
            for d, res in gcs.take_control().items():
                console.print(f"gcs: take_control {d}: {'ok' if res.success else 'FAILED'} {res.message}")
        progress: deque[str] = deque(maxlen=20)     # the mission's steps, shown under the dashboard
        abort = threading.Event()
        mission = _start_mission(gcs, gcs_run, console, result, progress, abort) if gcs_run.mission else None
        deadline = None if gcs_run.duration is None or gcs_run.mission else time.monotonic() + gcs_run.duration
        interrupted = False
        try:
            _watch(gcs, console, gcs_run, deadline, mission, progress)
        except KeyboardInterrupt:
            interrupted = True
            abort.set()     # the mission stops as it is: the drone holds where it is (mission.py)
            if mission is not None:
                mission.join(timeout=5.0)
        finally:
            gcs.release_control()
            node.shutdown()
            spinner.join(timeout=2.0)
        if interrupted:
            result["result"] = interrupted_line(gcs) if gcs_run.mission else ""
            console.print(f"gcs: interrupted{': ' + result['result'] if result['result'] else ''}")
        _report(gcs, gcs_run, console, extras, result)
    if interrupted:
        return 130
    if gcs_run.mission and not result.get("ok"):
        return 1
    return 0


def interrupted_line(gcs: Gcs) -> str:
    """What each drone is doing when the operator stopped the mission, and the command that lands it."""
    parts = []
    for d in sorted(gcs.drones.values(), key=lambda v: v.id):
        s = d.state
        if s is None:
            parts.append(f"{d.id}: never heard")
        elif s.armed and not s.landed:
            parts.append(f"{d.id} holding at {-s.position[2]:.1f} m, armed ({s.mode_label}); land it with "
                         f"`zenoh-robot gcs cmd {d.id} land`")
        else:
            parts.append(f"{d.id} on the ground, {'armed' if s.armed else 'disarmed'} ({s.mode_label})")
    return "interrupted by the operator: " + "; ".join(parts or ["no drone heard"])


def _start_mission(gcs: Gcs, gcs_run: GcsRun, console: Console, result: dict[str, Any], progress: deque[str],
                   abort: threading.Event) -> threading.Thread:
    """The mission on its own thread, its outcome into ``result``: the dashboard runs meanwhile and shows
    its steps (``progress``); without the dashboard they are printed as they come."""
    live = gcs_run.dashboard and console.is_terminal
    drones, duration = gcs_run.gcs.drones, gcs_run.duration or 60.0

    def say(line: str) -> None:
        progress.append(f"{time.strftime('%H:%M:%S')} {line}")
        if not live:
            _say(line)

    def mission() -> None:
        if len(drones) == 1:
            result.update(run_mission(gcs, drones[0], duration, say, abort, lambda: "interrupted by the operator"))
        else:
            result.update(run_swarm_mission(gcs, drones, duration, say, gcs_run.on_failure, abort))
    thread = threading.Thread(target=mission, name="mission", daemon=True)
    thread.start()
    return thread


def _report(gcs: Gcs, gcs_run: GcsRun, console: Console, extras: GcsExtras, result: dict[str, Any]) -> None:
    summary = summarize(gcs, gcs_run.gcs.profile.name)
    summary["mission"] = result
    extras.close(summary)
    print_summary(console, summary)
    if gcs_run.record:
        write_record(summary, gcs_run.record)
        console.print(f"gcs: figures written to {gcs_run.record}")
    if gcs_run.mission:
        console.print(f"gcs: mission {result.get('result') or 'FAILED: did not finish'}")


def _watch(gcs: Gcs, console: Console, gcs_run: GcsRun, deadline: float | None,
           mission: threading.Thread | None, progress: deque[str]) -> None:
    def done() -> bool:
        if mission is not None:
            return not mission.is_alive()
        return deadline is not None and time.monotonic() >= deadline

    rates = RateMeter()
    if not gcs_run.dashboard or not console.is_terminal:
        # Plain, short, periodic lines: a pipe or a log file gets no padding, no colours, no nan.
        last = time.monotonic()
        while not done():
            time.sleep(0.2)
            for d in list(gcs.drones.values()):
                rates_now = (len(d.streams["sensor"]), d.setpoints_sent)   # keep the windows filled
                rates.rate(f"{d.id}/sensor", rates_now[0])
                rates.rate(f"{d.id}/setpoint", rates_now[1])
            if time.monotonic() - last >= 5.0:
                last = time.monotonic()
                for line in plain_lines(gcs, rates):
                    _say(line)
        return
    # The alternate screen: the view is redrawn whole, so a drone joining leaves no stale header behind.
    def view() -> Any:   # as wide as the terminal is now (it may be resized)
        return render(gcs, rates, details=gcs_run.details, width=console.size.width, progress=list(progress))
    with Live(view(), console=console, refresh_per_second=4, screen=True) as live:
        while not done():
            time.sleep(0.25)
            live.update(view())
    for line in progress:       # the alternate screen is gone: the steps stay in the terminal
        console.print(line, highlight=False)


def _say(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


@dataclass(frozen=True)
class CommandRun:
    """One ``gcs cmd``, from its validated arguments."""
    name: str
    value: float
    text: str
    force: bool
    client_id: str
    drones: list[str]        # empty: 'all' without --drones, every drone heard within ``discover_s``
    discover_s: float
    timeout: float
    session: SessionConfig
    wire: WireFormat
    keyring: Keyring | None
    target: tuple[float, float, float] | None = None    # goto's point


def run_command(args: argparse.Namespace) -> int:
    try:
        cmd = parse_command(args)
    except UsageError as exc:
        print(f"gcs cmd: {exc}", file=sys.stderr)
        return 2
    log_startup_line(log, cmd.session, cmd.keyring)
    return send_command(cmd)


def parse_command(args: argparse.Namespace) -> CommandRun:
    target = None
    if args.command == "goto":
        name, value, text = "goto", 0.0, ""
        try:
            target = parse_target(args.value)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    else:
        name = str(resolve_cli_name(args.command))
        value, text = _command_argument(name, args.value)
    client_id = _client_id(args.gcs_id)
    session = session_config_from_args(args, name="gcs")
    wire, keyring = _link(args.link_keys, client_id, encrypt=False)
    drones = [d for d in (args.drones or "").split(",") if d] if args.drone == "all" else [args.drone]
    return CommandRun(name=name, value=value, text=text, force=args.force, client_id=client_id, drones=drones,
                      discover_s=args.discover, timeout=args.timeout, session=session, wire=wire, keyring=keyring,
                      target=target)


def _command_argument(name: str, arg: str | None) -> tuple[float, str]:
    """The command's (value, text) from its optional argument."""
    if name == "takeoff":
        if not arg:
            return 5.0, ""
        try:
            return float(arg), ""
        except ValueError:
            raise UsageError(f"takeoff altitude {arg!r} is not a number") from None
    if name == "set_param":
        if not arg or "=" not in arg:
            raise UsageError("set_param needs NAME=VALUE")
        text, _, raw = arg.partition("=")
        try:
            return float(raw), text
        except ValueError:
            raise UsageError(f"parameter value {raw!r} is not a number") from None
    if name in ("hand_over", "release_control"):
        if name == "hand_over" and not arg:
            raise UsageError("hand_over needs the GCS id to hand control over to")
        return 0.0, arg or ""
    return 0.0, ""


def send_command(cmd: CommandRun) -> int:
    with Node("gcs_cmd", config=cmd.session, wire=cmd.wire) as node:
        if cmd.target is not None:     # an action: its feedback and status arrive through the executor
            threading.Thread(target=node.spin, name="gcs-cmd-spin", daemon=True).start()
        targets = cmd.drones or discover_drones(node, cmd.discover_s)
        if not targets:
            print(f"gcs cmd: all: no drone heard within {cmd.discover_s:g} s (give --drones)", file=sys.stderr)
            return 1
        results, failed = _send_to_each(node, cmd, targets)
    for drone in targets:
        print(results.get(drone, f"{drone} {cmd.name}: FAILED no answer"))
    if len(targets) > 1:
        print(f"{cmd.name}: {len(targets) - len(failed)} of {len(targets)} ok"
              + (f"; FAILED: {', '.join(sorted(failed))}" if failed else ""))
    return 1 if failed else 0


def _send_to_each(node: Node, cmd: CommandRun, targets: list[str]) -> tuple[dict[str, str], list[str]]:
    """Every drone's answer line, and the drones that failed."""
    results: dict[str, str] = {}
    failed: list[str] = []
    name = cmd.name

    def one(drone: str) -> None:
        if cmd.target is not None:
            ok, line = send_goto(node, drone, cmd.client_id, cmd.target, cmd.timeout)
            results[drone] = line
            if not ok:
                failed.append(drone)
            return
        client = node.create_client(f"/{drone}/{COMMAND_SERVICE}", Command, CommandResult,
                                    retry=command_retry(node))
        try:
            res = client.call(Command(name, cmd.value, cmd.text, cmd.force, cmd.client_id), timeout=cmd.timeout)
        except ServiceCallError as exc:
            failed.append(drone)
            results[drone] = f"{drone} {name}: FAILED {type(exc).__name__}: {exc}"
            return
        if not res.success:
            failed.append(drone)
        results[drone] = f"{drone} {name}: {'ok' if res.success else 'FAILED'} {res.message} (mode {res.mode})"
    # All at once: `gcs cmd all land` must not land ten drones one timeout after another.
    threads = [threading.Thread(target=one, args=(d,), daemon=True) for d in targets]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return results, failed
