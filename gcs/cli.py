"""``zenoh-robot gcs``: stream setpoints, show the dashboard, fly a mission, send commands."""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live

from drone_contract.commands import CLI_COMMANDS, COMMAND_SERVICE, resolve_cli_name
from drone_contract.link_protection import link_wire, log_startup_line, reaches_network
from drone_contract.streams import IMAGE_MODES, PROFILES, StreamProfile, stream_profile
from zenoh_robot import Node, SessionConfig
from zenoh_robot.parameters import add_param_argument, params_from_args
from zenoh_robot.services import command_retry
from zenoh_robot.session_args import add_session_arguments, session_config_from_args
from zenoh_robot.wire import ENVELOPE, WireFormat

from .app import Gcs
from .config import GcsConfig
from .dashboard import RateMeter, plain_lines, render
from .discovery import discover_drones
from .formation import FORMATIONS, resolve
from .mission import ON_FAILURE, run_mission, run_swarm_mission
from .patterns import PATTERNS

log = logging.getLogger("gcs")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("gcs", help="ground control station: setpoints, telemetry, images, commands")
    add_common(p)
    actions = p.add_subparsers(dest="gcs_action", metavar="ACTION")
    c = actions.add_parser("cmd", help="send one command to a drone, or to all: arm, takeoff 5, land, hold, ...")
    c.add_argument("drone", help="a drone id, or 'all': every drone of --drones, else every drone heard "
                                 "within --discover s")
    c.add_argument("command", choices=CLI_COMMANDS)
    c.add_argument("value", nargs="?", help="takeoff altitude, NAME=VALUE for set_param, or the GCS id to "
                                           "hand control over to (hand_over, release_control)")
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


def run(args: argparse.Namespace) -> int:
    if args.gcs_action == "cmd":
        return run_command(args)
    params = params_from_args(args)
    profile = stream_profile(args.profile, params, image_mode=args.image)
    drones = [d for d in (args.drones or "").split(",") if d]
    client_id = _client_id(args)
    if client_id is None:
        return 2
    patterns = {}
    for item in (x for x in args.patterns.split(",") if x):
        drone, sep, name = item.partition("=")
        if not sep or name not in PATTERNS:
            print(f"gcs: --patterns {item!r}: expected ID=PATTERN, PATTERN one of {', '.join(PATTERNS)}",
                  file=sys.stderr)
            return 2
        patterns[drone] = name
    if len(set(drones)) != len(drones):
        print(f"gcs: --drones names a drone twice: {args.drones}", file=sys.stderr)
        return 2
    if args.spacing <= 0:
        print("gcs: --spacing must be > 0 m", file=sys.stderr)
        return 2
    for flag, v in (("--sensor-rate", args.sensor_rate), ("--camera-rate", args.camera_rate)):
        if v is not None and not (math.isfinite(v) and v > 0):
            print(f"gcs: {flag} must be > 0 Hz, got {v!r}", file=sys.stderr)
            return 2
    config = GcsConfig(drones=drones, pattern=args.pattern, rate_hz=args.rate, altitude=args.altitude,
                       size=args.size, speed=args.speed, profile=profile, save_image=args.save_image,
                       save_every=args.save_every, client_id=client_id, take_control=args.take_control,
                       auto_fly=not args.mission, formation=resolve(args.formation, len(drones) or 2),
                       spacing=args.spacing, patterns=patterns, sensor_rate_hz=args.sensor_rate,
                       camera_rate_hz=args.camera_rate)
    console = Console(stderr=False)
    if args.save_image and len(drones) != 1:
        console.print(f"gcs: --save-image: one file per drone, "
                      f"{args.save_image.with_name(args.save_image.stem + '_<id>' + args.save_image.suffix)} "
                      "(each name is printed when first written)")
    session = session_config(args, profile)
    wire: WireFormat = ENVELOPE
    keyring = None
    if args.link_keys:   # the keyring of this GCS's id: its key is what "the GCS in control" means
        try:
            wire, keyring = link_wire(args.link_keys, client_id, encrypt=args.link_encrypt)
        except ValueError as exc:
            print(f"gcs: --link-keys: {exc}", file=sys.stderr)
            return 2
    log_startup_line(log, session, keyring, args.link_encrypt)
    if args.mission and not (session.secure or keyring) and reaches_network(session) and not args.insecure_ok:
        # One flag must not be all that stands between a field flight and an open link.
        print("gcs: --mission over a network without --secure: commands would be unauthenticated (a peer can "
              "claim this GCS's client id); give --secure DIR or --link-keys DIR, or --insecure-ok to fly anyway",
              file=sys.stderr)
        return 2
    with Node("gcs", config=session, parameter_overrides=params, wire=wire,
              enable_topic_statistics=not args.no_topic_statistics) as node:
        gcs = Gcs(node, config)
        from .mavlink_out import GcsExtras
        extras = GcsExtras(node, args, drones, console.print)
        spinner = threading.Thread(target=node.spin, name="gcs-spin", daemon=True)
        spinner.start()
        result: dict[str, Any] = {}
        mission_thread = None
        if args.take_control:
            if not drones:
                console.print("gcs: --take-control needs --drones (which drones to take)")
                node.shutdown()
                return 2
            for d, res in gcs.take_control().items():
                console.print(f"gcs: take_control {d}: {'ok' if res.success else 'FAILED'} {res.message}")
        if args.mission:
            if not drones:
                console.print("gcs: --mission needs the drones to fly (--drones uav1,uav2)")
                node.shutdown()
                return 2
            say = console.log if console.is_terminal else _say

            def mission() -> None:
                if len(drones) == 1:
                    result.update(run_mission(gcs, drones[0], args.duration or 60.0, say))
                else:
                    result.update(run_swarm_mission(gcs, drones, args.duration or 60.0, say, args.on_failure))
            mission_thread = threading.Thread(target=mission, name="mission", daemon=True)
            mission_thread.start()
        deadline = None if args.duration is None or args.mission else time.monotonic() + args.duration
        try:
            _watch(gcs, console, args, deadline, mission_thread)
        except KeyboardInterrupt:
            console.print("gcs: interrupted")
        finally:
            gcs.release_control()
            node.shutdown()
            spinner.join(timeout=2.0)
        summary = summarize(gcs, profile.name)
        summary["mission"] = result
        extras.close(summary)
        _print_summary(console, summary)
        if args.record:
            write_record(summary, args.record)
            console.print(f"gcs: figures written to {args.record}")
        if args.mission:
            console.print(f"gcs: mission {result.get('result') or 'FAILED: did not finish'}")
    if args.mission and not result.get("ok"):
        return 1
    return 0


def _client_id(args: argparse.Namespace) -> str | None:
    from drone_contract.messages import valid_client_id

    from .config import default_client_id
    cid = args.gcs_id or default_client_id()
    if not valid_client_id(cid):
        print(f"gcs: --gcs-id {cid!r}: letters, digits and _.@:+- only, at most 64", file=sys.stderr)
        return None
    return cid


def _watch(gcs: Gcs, console: Console, args: argparse.Namespace, deadline: float | None,
           mission: threading.Thread | None) -> None:
    def done() -> bool:
        if mission is not None:
            return not mission.is_alive()
        return deadline is not None and time.monotonic() >= deadline

    rates = RateMeter()
    if args.no_dashboard or not console.is_terminal:
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
    with Live(render(gcs, rates, details=args.details), console=console, refresh_per_second=4, screen=True) as live:
        while not done():
            time.sleep(0.25)
            live.update(render(gcs, rates, details=args.details))


def _say(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", flush=True)


def summarize(gcs: Gcs, profile: str) -> dict[str, Any]:
    out: dict[str, Any] = {"profile": profile, "pattern": gcs.config.pattern, "formation": gcs.config.formation,
                           "drones": {}}
    # Late copies left together and could be lost together: a starved repeater, not the link.
    out["repeater"] = gcs.node.repeater_stats()
    # The rates asked of each drone (None: its own): received rates are judged against these.
    out["downlink_asked"] = {"sensor_rate_hz": gcs.config.sensor_rate_hz, "camera_rate_hz": gcs.config.camera_rate_hz}
    for d in gcs.drones.values():
        streams = {name: rec.summary().as_dict() for name, rec in d.streams.items()}
        for name in d.streams:
            streams[name]["lost_pct"] = d.lost_pct(name)
        out["drones"][d.id] = {
            "setpoints_sent": d.setpoints_sent, "streams": streams,
            "frames": d.image.frames, "frames_complete": d.image.complete,
            "frames_decoded": d.frames.decoded, "decode_cpu_s": d.frames.decode_s,
            "slot": list(d.slot), "pattern": d.pattern_name,
            "max_path_error_m": d.plan.max_path_error,
            # Against the drone's own (slot's) path, from when it joined it (gcs/planner.py, PATH_JOIN_M).
            "mean_path_error_m": d.plan.mean_path_error, "path_error_samples": d.plan.path_error_samples,
            "joined_path": d.plan.on_path,
            "final_state": d.state.to_dict() if d.state else None,
            "events": [e.to_dict() for e in d.events],
            "downlink": gcs.downlink.status[d.id].as_dict()
            if gcs.downlink is not None and d.id in gcs.downlink.status else None,
            # Raw (seq, stamp, arrival) records for offline analysis (the experiment joins them
            # with the companion's to get exact delivered % over a time window).
            "logs": {"sent": {k: v.to_dict() for k, v in d.sent.items()},
                     "received": {k: v.to_dict() for k, v in d.streams.items()}},
        }
    return out


def write_record(summary: dict[str, Any], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() != ".csv":
        from zenoh_robot.tools.bag.schemas import jsonable  # strict JSON: NaN -> null
        if path.suffix.lower() == ".mcap":    # the flight log itself was written live (GcsExtras)
            path = path.with_suffix(".summary.json")
        path.write_text(json.dumps(jsonable(summary), indent=2, default=str, allow_nan=False))
        return
    import csv
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        fields = ["received", "unique", "lost_pct", "age_avg_ms", "age_p50_ms", "age_p99_ms", "age_max_ms",
                  "period_avg_ms", "period_max_ms", "longest_gap_ms", "rate_hz"]
        w.writerow(["profile", "drone", "stream", *fields])
        for drone, d in summary["drones"].items():
            for name, s in d["streams"].items():
                w.writerow([summary["profile"], drone, name, *(s.get(k) for k in fields)])


def _print_summary(console: Console, summary: dict[str, Any]) -> None:
    from rich.table import Table
    t = Table(title=f"summary ({summary['profile']})")
    for col in ("drone", "stream", "received", "lost %", "age avg ms", "age p99 ms", "period avg ms"):
        t.add_column(col)
    for drone, d in summary["drones"].items():
        for name, s in d["streams"].items():
            t.add_row(drone, name, str(s["received"]), f"{s['lost_pct']:.1f}", f"{s['age_avg_ms']:.1f}",
                      f"{s['age_p99_ms']:.1f}", f"{s['period_avg_ms']:.1f}")
        console.print(f"{drone}: setpoints sent {d['setpoints_sent']}, frames {d['frames']} "
                      f"({d['frames_complete']} whole), largest distance from the path "
                      f"{d['max_path_error_m']:.2f} m (mean {d['mean_path_error_m']:.2f} m, against its own path)")
        if d.get("downlink"):
            asked = {k: v for k, v in summary.get("downlink_asked", {}).items() if v is not None}
            console.print(f"{drone}: downlink asked {asked}: {d['downlink']['status']} {d['downlink']['detail']}")
    console.print(t)


def run_command(args: argparse.Namespace) -> int:
    from drone_contract.messages import Command, CommandResult
    from zenoh_robot.services import ServiceCallError
    name = str(resolve_cli_name(args.command))
    value, text = 0.0, ""
    if name == "takeoff":
        value = float(args.value) if args.value else 5.0
    elif name == "set_param":
        if not args.value or "=" not in args.value:
            print("gcs cmd: set_param needs NAME=VALUE", file=sys.stderr)
            return 2
        text, _, raw = args.value.partition("=")
        try:
            value = float(raw)
        except ValueError:
            print(f"gcs cmd: parameter value {raw!r} is not a number", file=sys.stderr)
            return 2
    elif name in ("hand_over", "release_control"):
        text = args.value or ""
        if name == "hand_over" and not text:
            print("gcs cmd: hand_over needs the GCS id to hand control over to", file=sys.stderr)
            return 2
    client_id = _client_id(args)
    if client_id is None:
        return 2
    config = session_config_from_args(args, name="gcs")
    wire: WireFormat = ENVELOPE
    keyring = None
    if args.link_keys:
        try:
            wire, keyring = link_wire(args.link_keys, client_id)
        except ValueError as exc:
            print(f"gcs cmd: --link-keys: {exc}", file=sys.stderr)
            return 2
    log_startup_line(log, config, keyring)
    with Node("gcs_cmd", config=config, wire=wire) as node:
        if args.drone == "all":
            targets = [d for d in (args.drones or "").split(",") if d] or discover_drones(node, args.discover)
            if not targets:
                print(f"gcs cmd: all: no drone heard within {args.discover:g} s (give --drones)", file=sys.stderr)
                return 1
        else:
            targets = [args.drone]
        results: dict[str, str] = {}
        failed: list[str] = []

        def one(drone: str) -> None:
            client = node.create_client(f"/{drone}/{COMMAND_SERVICE}", Command, CommandResult,
                                        retry=command_retry(node))
            try:
                res = client.call(Command(name, value, text, args.force, client_id), timeout=args.timeout)
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
    for drone in targets:
        print(results.get(drone, f"{drone} {name}: FAILED no answer"))
    if len(targets) > 1:
        print(f"{name}: {len(targets) - len(failed)} of {len(targets)} ok"
              + (f"; FAILED: {', '.join(sorted(failed))}" if failed else ""))
    return 1 if failed else 0

