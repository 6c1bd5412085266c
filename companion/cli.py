"""``zenoh-robot companion``: bridge one drone's PX4 to Zenoh."""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from drone_contract.link_protection import link_wire, log_startup_line
from drone_contract.streams import IMAGE_MODES, PROFILES, STREAMS, StreamProfile, stream_profile
from px4_link import CommandError, Px4Link
from px4_link.connection_url import DEFAULT_BAUD, Px4UrlError, check_serial_device, forms_line, parse_px4_url
from px4_link.targets import DEFAULT_FENCE_CEILING_M, DEFAULT_FENCE_FLOOR_M, DEFAULT_FENCE_RADIUS_M, Geofence
from px4_link.vehicle import VehicleLink
from zenoh_robot import Node
from zenoh_robot.names import validate_node_name
from zenoh_robot.parameters import ParameterError, ParameterStore, add_param_argument, params_from_args
from zenoh_robot.qos import load_qos
from zenoh_robot.session_args import add_session_arguments, session_config_from_args
from zenoh_robot.wire import ENVELOPE, WireFormat

from .app import Companion
from .config import DEFAULT_PARAM_ALLOW, CompanionConfig
from .params import PX4_STREAMS, QOS_PARAMS, CompanionParameters, known_names
from .px4_mode import ModeReadiness
from .summary import summary_line, write_summary

log = logging.getLogger("companion")
# Loopback: PX4 SITL or a local autopilot bridge. On a drone whose autopilot is another host on the
# airframe's network, pass its address (e.g. udpin:0.0.0.0:14540 with a firewall): the link locks onto
# the first autopilot it hears and ignores frames from elsewhere.
DEFAULT_PX4 = "udpin:127.0.0.1:14540"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("companion", help="drone side: PX4 <-> Zenoh, camera, commands, link-loss failsafe")
    p.add_argument("--config-file", type=Path, metavar="YAML",
                   help="the drone's settings: each key a flag's long name (id, px4, profile, iface, link-keys, "
                        "camera, sensor-rate, ...), each value what the flag takes; a flag on the command line "
                        "wins (docs/hardware.md)")
    p.add_argument("--id", default="uav1", help="drone id, the namespace of its topics (default uav1)")
    p.add_argument("--px4", default=DEFAULT_PX4,
                   help=f"PX4 MAVLink connection (default {DEFAULT_PX4}, where PX4 SITL sends): a serial or USB "
                        "device with an optional baud, /dev/ttyAMA0:921600, /dev/ttyACM0, /dev/serial/by-id/... "
                        f"(default {DEFAULT_BAUD}: PX4's TELEM2 default, SER_TEL2_BAUD; USB ignores it; MAVSDK's "
                        "57600 is the radio port's); MAVSDK's URLs serial:///dev/ttyACM0:57600, udp://:14540, "
                        "udpin://0.0.0.0:14540, udpout://HOST:PORT, tcp://HOST:PORT; pymavlink's udpin:HOST:PORT; "
                        "'sim' starts the built-in simulator; PX4's own Zenoh module (no MAVLink): 'zenoh' "
                        "(an embedded router on tcp/127.0.0.1:7447, PX4 SITL's default, that PX4 joins), "
                        "'zenoh:<endpoint>' (a client of the router there), 'zenoh-sim' (the built-in simulator "
                        "speaking PX4's Zenoh)")
    p.add_argument("--px4-msgs", type=Path, metavar="DIR",
                   help="with --px4 zenoh*: PX4's msg/ directory, whose definitions (and so type hashes) PX4 was "
                        "built with (default: the bundled px4_msgs of PX4 main 2026-03)")
    p.add_argument("--px4-mode", metavar="NAME",
                   help="with --px4 zenoh*: fly as a PX4 external mode named NAME (<= 24 bytes) instead of OFFBOARD: "
                        "registered with PX4, its arming check answered from the companion's state, selected by "
                        "the GCS's offboard_start (docs/px4-zenoh.md)")
    p.add_argument("--px4-replace", choices=("rtl",), metavar="rtl",
                   help="with --px4 zenoh*: register the companion's own RTL as the replacement of PX4's (climb to "
                        "10 m above home, straight back, descend, land); PX4 flies its own RTL again ~1 s after "
                        "the companion dies (docs/px4-zenoh.md)")
    p.add_argument("--px4-executor", action="store_true",
                   help="with --px4-mode NAME: own the mission as a PX4 mode executor (offboard_start: arm, take off, "
                        "the mode, then the GCS's rtl ends it and PX4's RTL lands), PX4's failsafes still in "
                        "charge; needs a PX4 whose zenoh bridge routes vehicle_command_mode_executor (PX4 PR "
                        "#26564; PX4_ZENOH_BRIDGE_FIXED=1), refused otherwise")
    p.add_argument("--sysid", type=int, default=1, help="system id of the built-in simulator (with --px4 sim)")
    p.add_argument("--profile", choices=sorted(PROFILES), default="resilient")
    p.add_argument("--config", type=Path, help="QoS YAML overriding streams (setpoint, sensor, state, image, events)")
    p.add_argument("--iface", help="network interface towards the GCS for the multicast transport "
                   "(profiles resilient, resilient_multicast; required by the latter)")
    add_session_arguments(p)
    p.add_argument("--link-keys", metavar="DIR", default=os.environ.get("ZR_LINK_KEYS"),
                   help="seal every topic sample (ChaCha20-Poly1305, replay window, per-role keys) with this "
                        "node's keyring DIR/<id>.json from `zenoh-robot keys link` (docs/security.md); "
                        "re-read on SIGHUP; default $ZR_LINK_KEYS")
    p.add_argument("--link-encrypt", action="store_true", help="with --link-keys: encrypt samples too")
    p.add_argument("--no-topic-statistics", action="store_true",
                   help="do not publish per-stream statistics (what `zenoh-robot stats` shows)")
    p.add_argument("--deadline", type=float, default=1.0,
                   help="setpoint deadline before HOLD, s (default 1; the GCS offers 0.5, "
                        "so a shorter one is an incompatible QoS pair)")
    p.add_argument("--resume-on-setpoints", action="store_true",
                   help="after a failsafe HOLD, resume OFFBOARD by itself when setpoints return")
    p.add_argument("--camera", default="test", help="'test' pattern, a device, a video file, or 'none'")
    p.add_argument("--camera-rate", type=float, default=30.0)
    p.add_argument("--image", choices=IMAGE_MODES,
                   help="raw rgb8 (as the thesis), one JPEG per frame, or sliced JPEG; default: the profile's")
    p.add_argument("--jpeg-quality", type=int, help="JPEG quality 1..95 (default: the profile's)")
    p.add_argument("--sensor-rate", type=float, default=200.0, help="HIGHRES_IMU rate asked of PX4, Hz")
    p.add_argument("--px4-streams", choices=PX4_STREAMS, default="lean",
                   help="lean (default): ask PX4 only for the telemetry the companion reads, at the rates it "
                        "needs, the rest off; default: PX4's own streams (always so with --mavlink-tunnel)")
    p.add_argument("--max-offset", type=float, default=10.0,
                   help="farthest a position setpoint may lie from the vehicle, m (default 10)")
    p.add_argument("--fence-radius", type=float, default=DEFAULT_FENCE_RADIUS_M,
                   help="geofence: farthest horizontal distance from home any setpoint may take the drone, m "
                        "(default %(default)g; position setpoints beyond are refused, velocity ones stop at it)")
    p.add_argument("--fence-ceiling", type=float, default=DEFAULT_FENCE_CEILING_M,
                   help="geofence ceiling above home, m (default %(default)g)")
    p.add_argument("--fence-floor", type=float, default=DEFAULT_FENCE_FLOOR_M,
                   help="geofence floor above home, m: the lowest any setpoint may take the drone "
                        "(default %(default)g, never below home; landing is PX4's land mode)")
    p.add_argument("--control-lease", type=float, default=5.0,
                   help="a GCS in control without a liveliness token loses control after this silence, s")
    p.add_argument("--allow-force-disarm", action="store_true",
                   help="accept `disarm --force` in flight (motors stop: the vehicle falls); refused by default")
    p.add_argument("--param-allow", default=",".join(DEFAULT_PARAM_ALLOW),
                   help="comma-separated PX4 parameters a GCS may set (default: %(default)s)")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--record", type=Path, help="write the setpoint stream's figures here (JSON) at exit")
    p.add_argument("--vehicle-record", type=Path, metavar="FILE",
                   help="sample the vehicle side every 20 ms into FILE (JSONL): PX4's mode, armed, position, the "
                        "offboard session and the source stamp of the target PX4 is given (what the lossy-link "
                        "experiment measures)")
    p.add_argument("--vehicle-record-max-mb", type=float, default=100.0, metavar="MB",
                   help="--vehicle-record's size cap: past it FILE becomes FILE.1 (replacing the older one) and "
                        "a new FILE starts, so at most twice this is on disk (default %(default)g; 0: no cap)")
    p.add_argument("--ros2-topics", action="store_true",
                   help="also publish the drone as standard ROS 2 types on rmw_zenoh's wire (/<id>/imu, pose, fix, "
                        "battery, image/compressed; ROS domain: --ros-domain-id, else env ROS_DOMAIN_ID, else 0); "
                        "--ros2 or --ros-domain-id imply it (docs/ros2.md)")
    p.add_argument("--mavlink-tunnel", action="store_true",
                   help="forward PX4's MAVLink over Zenoh (<id>/mavlink/down|up) for a QGC on the GCS "
                        "(gcs --mavlink-out)")
    p.add_argument("--mavlink-tunnel-allow-control", action="store_true",
                   help="let QGC's commands, setpoints and writes through the tunnel (default: read-only, refused)")
    add_param_argument(p)
    p.set_defaults(func=run)


def load_profile(args: argparse.Namespace, params: dict[str, Any]) -> StreamProfile:
    profile = stream_profile(args.profile, params, image_mode=args.image, jpeg_quality=args.jpeg_quality)
    if args.config:
        overrides = load_qos(args.config)
        unknown = sorted(set(overrides) - set(STREAMS))
        if unknown:
            raise ValueError(f"{args.config}: unknown stream(s) {unknown}; streams: {', '.join(STREAMS)}")
        profile = replace(profile, name=f"{profile.name}+{args.config.stem}", qos={**profile.qos, **overrides})
    return profile


@contextlib.contextmanager
def px4_connection(spec: str, sysid: int) -> Iterator[str]:
    """Yield a pymavlink connection string; with 'sim', run the built-in simulator meanwhile."""
    if spec != "sim":
        yield spec
        return
    from px4_link.sim import Simulator
    port = _free_udp_port()
    with Simulator(sysid, port=0, target_port=port):
        yield f"udpin:127.0.0.1:{port}"


@contextlib.contextmanager
def vehicle_link(args: argparse.Namespace, geofence: Geofence,
                 readiness: ModeReadiness | None = None) -> Iterator[tuple[VehicleLink, Any, str]]:
    """(link, the MAVLink tunnel's end at PX4 or None, what it is connected to): px4_link over MAVLink, or
    px4_zenoh over PX4's own Zenoh module on a session of its own (never the GCS-facing node's); with
    ``--px4-mode`` the link's offboard flies through that PX4 external mode, answered by ``readiness``.
    The tunnel's end is a UDP tee before the link, or on a serial link a tap on it (mavlink_tunnel.py)."""
    from .mavlink_tunnel import maybe_tap, maybe_tee
    if args.px4 == "zenoh-sim" or args.px4 == "zenoh" or args.px4.startswith("zenoh:"):
        if args.mavlink_tunnel:
            raise ValueError(f"--mavlink-tunnel needs PX4's MAVLink; --px4 {args.px4} has none")
        from px4_zenoh import Px4ZenohLink, parse_px4_spec
        from px4_zenoh.session import Px4Endpoint, free_tcp_endpoint
        where = parse_px4_spec(args.px4) or Px4Endpoint("router", free_tcp_endpoint())
        with Px4ZenohLink(where, msg_dir=args.px4_msgs, geofence=geofence) as zlink, \
                _external_mode(zlink, getattr(args, "px4_mode", None), readiness,
                               getattr(args, "px4_executor", False)), \
                _replacement(zlink, getattr(args, "px4_replace", None)):
            if args.px4 != "zenoh-sim":
                yield zlink, None, str(where)
                return
            from px4_zenoh.sim import ZenohSimulator
            with ZenohSimulator(connect=where.endpoint, sysid=args.sysid):
                yield zlink, None, f"{where} (built-in Zenoh simulator)"
        return
    if args.px4_msgs is not None:
        raise ValueError("--px4-msgs: only with --px4 zenoh, zenoh:<endpoint> or zenoh-sim")
    for flag in ("px4_mode", "px4_replace", "px4_executor"):
        if getattr(args, flag, None):
            raise ValueError(f"--{flag.replace('_', '-')}: only with --px4 zenoh, zenoh:<endpoint> or zenoh-sim "
                             "(PX4's zenoh module)")
    # UDP: the tunnel is a tee in front of the link; a serial port has one holder, the link, so there
    # the tunnel taps the link itself (mavlink_tunnel.py).
    with px4_connection(args.px4, args.sysid) as px4_conn, maybe_tee(args.mavlink_tunnel, px4_conn) as (tee, conn), \
            Px4Link(conn, geofence=geofence) as link, maybe_tap(args.mavlink_tunnel and tee is None, link) as tap:
        yield link, tee if tee is not None else tap, conn


@contextlib.contextmanager
def _external_mode(zlink: Any, name: str | None, readiness: ModeReadiness | None,
                   executor: bool = False) -> Iterator[None]:
    """With a mode name: the link's offboard becomes that PX4 external mode (owned by a mode executor with
    ``executor``), unregistered on the way out."""
    if not name:
        if executor:
            raise ValueError("--px4-executor: needs --px4-mode NAME (the mode the executor owns)")
        yield
        return
    from px4_zenoh.external_mode import BridgeBugError
    from px4_zenoh.external_mode.offboard import install
    check = (readiness or ModeReadiness()).check
    try:
        mode = install(zlink, name, check, executor=executor)
    except BridgeBugError:
        raise ValueError(executor_refusal()) from None
    try:
        yield
    finally:
        mode.close()


def executor_refusal() -> str:
    """--px4-executor on a PX4 not declared fixed, in one line."""
    from px4_zenoh.external_mode.bridge import ENV_FIXED
    return ("--px4-executor refused: this PX4's zenoh module delivers /fmu/in/vehicle_command_mode_executor to "
            "uORB vehicle_command, so PX4 would run the executor's commands without checking it is in charge "
            f"(its failsafes and the pilot could be overridden); needs PX4 PR #26564 (set {ENV_FIXED}=1 for a "
            "PX4 with it)")


@contextlib.contextmanager
def _replacement(zlink: Any, which: str | None) -> Iterator[None]:
    """With --px4-replace rtl: the companion's RTL replaces PX4's while the companion lives."""
    if not which:
        yield
        return
    from px4_zenoh.external_mode.offboard import install_rtl
    rtl = install_rtl(zlink)
    try:
        yield
    finally:
        rtl.close()


def _free_udp_port() -> int:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def check_px4(spec: str) -> str | None:
    """What is wrong with ``--px4``, in one line (None: nothing), before anything is opened: a serial
    device that is missing or not ours to open is a start-up mistake, as a misspelt form is."""
    if spec in ("sim", "zenoh", "zenoh-sim") or spec.startswith("zenoh:"):
        return None
    try:
        check_serial_device(parse_px4_url(spec))
    except Px4UrlError as exc:
        if exc.unknown_form:
            return f"{spec!r} is not a PX4 connection; {forms_line()}; or sim, zenoh, zenoh:ENDPOINT, zenoh-sim"
        return str(exc)
    return None


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.tools.cli.main import CliError
    try:
        validate_node_name(args.id)
    except ValueError as exc:
        raise CliError(f"--id: {exc}") from None
    px4_problem = check_px4(args.px4)
    if px4_problem is not None:   # a usage mistake, as argparse's: one line and exit 2
        print(f"companion: --px4: {px4_problem}", file=sys.stderr)
        return 2
    if getattr(args, "px4_executor", False):
        from px4_zenoh.external_mode import BridgePolicy
        if not BridgePolicy.from_env().fixed:   # refused before PX4 or Zenoh is opened: nothing half-started
            print(f"companion: {executor_refusal()}", file=sys.stderr)
            return 2
    params = params_from_args(args)
    try:
        profile = load_profile(args, params)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    config = CompanionConfig(drone_id=args.id, profile=profile, setpoint_deadline=args.deadline,
                             resume_on_setpoints=args.resume_on_setpoints, sensor_rate_hz=args.sensor_rate,
                             camera=None if args.camera == "none" else args.camera, camera_rate_hz=args.camera_rate,
                             max_offset_m=args.max_offset, control_lease_s=args.control_lease,
                             fence_radius_m=args.fence_radius, fence_ceiling_m=args.fence_ceiling,
                             fence_floor_m=args.fence_floor,
                             allow_force_disarm=args.allow_force_disarm, px4_streams=args.px4_streams,
                             mavlink_tunnel=args.mavlink_tunnel,
                             param_allow=tuple(n for n in args.param_allow.split(",") if n),
                             qos_overrides={k: params[k] for k in QOS_PARAMS if k in params})
    unknown = sorted(set(params) - known_names())
    if unknown:
        raise CliError(f"-p {', '.join(unknown)}: not a companion parameter; parameters: "
                       f"{', '.join(sorted(known_names()))}")
    try:   # every -p value checked now, before PX4 or Zenoh is opened
        in_force = CompanionParameters(config).declare(ParameterStore(params))
    except ParameterError as exc:
        raise CliError(f"-p: {exc}") from None
    try:   # the profile says unicast or multicast; multicast needs --iface (one-line error otherwise)
        session = session_config_from_args(args, lambda: profile.session_config(args.iface), args.id)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    wire: WireFormat = ENVELOPE
    keyring = None
    if args.link_keys:
        try:
            wire, keyring = link_wire(args.link_keys, args.id, encrypt=args.link_encrypt)
        except ValueError as exc:
            raise CliError(f"--link-keys: {exc}") from None
    log_startup_line(log, session, keyring, args.link_encrypt)
    from zenoh_robot import MultiThreadedExecutor
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    from .mavlink_tunnel import MavlinkTunnel
    px4_side = contextlib.ExitStack()
    readiness = ModeReadiness() if getattr(args, "px4_mode", None) else None
    try:
        link, tee, connection = px4_side.enter_context(vehicle_link(args, in_force.geofence(), readiness))
    except (ValueError, ConnectionError, FileNotFoundError, KeyError) as exc:
        px4_side.close()
        raise CliError(f"--px4 {args.px4}: {exc}") from None
    with px4_side, Node("companion", namespace=args.id, config=session, executor=MultiThreadedExecutor(3), wire=wire,
                        parameter_overrides=params, enable_topic_statistics=not args.no_topic_statistics,
                        settle_name=True) as node:   # one companion per drone id, whatever order sessions start in
        log.info("companion %s: PX4 at %s, profile %s", args.id, connection, profile.name)
        if not link.wait_connected(timeout=3.0):
            log.warning("no PX4 heartbeat yet on %s; waiting in the background (the sensor rate is asked "
                        "when PX4 appears)", connection)
        companion = Companion(node, link, config)
        if readiness is not None:   # PX4's arming checks are answered from the companion's state from now on
            readiness.bind(companion)
            log.info("companion %s: flying as PX4 external mode %r (not OFFBOARD)", args.id, args.px4_mode)
        ros2_topics = _ros2_streams(args, session, link, companion)
        if tee is not None:
            MavlinkTunnel(node, tee, allow_control=args.mavlink_tunnel_allow_control)
        if link.connected:   # else the companion asks on PX4's first heartbeat; px4_link after reconnects
            try:
                companion.telemetry.request_rates()
            except CommandError as exc:   # PX4's default rate applies until it reconnects
                log.warning("could not set the HIGHRES_IMU rate: %s", exc)
            companion.telemetry.request_streams()   # logs what PX4 refused; never raises a CommandError
        companion.on_yield = stop.set    # a second companion with this id came first: this one stops
        spinner = threading.Thread(target=node.spin, name="companion-spin", daemon=True)
        spinner.start()
        if args.vehicle_record:
            cap = int(args.vehicle_record_max_mb * 1e6) if args.vehicle_record_max_mb > 0 else None
            threading.Thread(target=_record_vehicle, args=(companion, link, args.vehicle_record, stop, cap),
                             name="vehicle-record", daemon=True).start()
        try:
            stop.wait(timeout=args.duration)
        except KeyboardInterrupt:
            pass
        finally:
            node.shutdown()
            spinner.join(timeout=2.0)
            if ros2_topics is not None:   # after the camera stopped (node.shutdown), before the link goes
                ros2_topics.close()
        companion.settle()
        summary = companion.summary()
        log.info("%s", summary_line(args.id, connection, summary))
        if args.record:
            write_summary(args.record, summary)
        stop.set()     # the vehicle record's last lines
    if companion.yielded:
        print(f"companion: {companion.yielded}", file=sys.stderr)
        return 1
    return 0


def _ros2_streams(args: argparse.Namespace, session: Any, link: VehicleLink, companion: Companion) -> Any:
    """The ROS 2 topics (ros2_streams.py) when asked for, else None."""
    from zenoh_robot.session_args import wire_from_args
    if not args.ros2_topics and wire_from_args(args) is ENVELOPE:
        return None
    from .ros2_streams import Ros2Streams
    streams = Ros2Streams(link, args.id, getattr(args, "ros_domain_id", None), session)
    if companion.camera is not None:
        companion.camera.frame_listeners.append(streams.on_frame)
    if companion.actions is not None and companion.node.wire is ENVELOPE:
        # The drone's actions for ROS 2 clients too, beside the topics. Not on a sealed companion: ROS 2's
        # wire carries no seal, and nothing unsealed may command a sealed drone.
        from .flight_actions import FlightActions
        actions = FlightActions(streams.node, companion.desk, link)
        streams.node.add_on_close(actions.close)
        threading.Thread(target=streams.node.spin, name="ros2-actions-spin", daemon=True).start()
    elif companion.actions is not None and args.link_keys:
        log.info("the drone's actions are not offered on ROS 2's wire: this companion's link is sealed "
                 "(--link-keys) and ROS 2's wire is not")
    return streams


def _record_vehicle(companion: Companion, link: VehicleLink, path: Path, stop: threading.Event,
                    max_bytes: int | None = None, period_s: float = 0.02) -> None:
    """One JSON line per ``period_s`` (wall ns ``t``, as the GCS stamps its setpoints): a target's
    age at the vehicle is ``t - sp_stamp``, sampled, so under by at most one period. Past ``max_bytes``
    the file becomes ``<path>.1`` and a new one starts: a companion that runs for days fills no disk."""
    import json
    import os
    import time

    from px4_link.telemetry import LocalPosition
    while not stop.is_set():
        written = 0
        with path.open("w", buffering=1) as f:     # line-buffered: the process may end before the thread
            while not stop.wait(period_s) and (max_bytes is None or written < max_bytes):
                pos = link.telemetry.latest(LocalPosition)
                last = companion.gate.last_forwarded
                line = json.dumps({
                    "t": time.time_ns(), "mode": link.mode, "armed": link.armed,
                    "session": companion.lifecycle.state.value,
                    "pos": None if pos is None else [round(pos.x, 3), round(pos.y, 3), round(pos.z, 3)],
                    "sp_stamp": None if last is None else last[1], "sp_seq": None if last is None else last[2],
                    "failsafes": companion.failsafe.triggered}) + "\n"
                f.write(line)
                written += len(line)
        if not stop.is_set():
            os.replace(path, path.with_name(path.name + ".1"))
