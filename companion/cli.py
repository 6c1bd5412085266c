"""``zenoh-robot companion``: bridge one drone's PX4 to Zenoh."""
from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import threading
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from drone_contract.link_protection import link_wire, log_startup_line
from drone_contract.streams import IMAGE_MODES, PROFILES, STREAMS, StreamProfile, stream_profile
from px4_link import CommandError, Px4Link
from px4_link.targets import DEFAULT_FENCE_CEILING_M, DEFAULT_FENCE_FLOOR_M, DEFAULT_FENCE_RADIUS_M
from zenoh_robot import Node
from zenoh_robot.names import validate_node_name
from zenoh_robot.parameters import ParameterError, ParameterStore, add_param_argument, params_from_args
from zenoh_robot.qos import load_qos
from zenoh_robot.session_args import add_session_arguments, session_config_from_args
from zenoh_robot.wire import ENVELOPE, WireFormat

from .app import Companion
from .config import DEFAULT_PARAM_ALLOW, CompanionConfig
from .params import PX4_STREAMS, QOS_PARAMS, CompanionParameters, known_names
from .summary import summary_line, write_summary

log = logging.getLogger("companion")
# Loopback: PX4 SITL or a local autopilot bridge. On a drone whose autopilot is another host on the
# airframe's network, pass its address (e.g. udpin:0.0.0.0:14540 with a firewall): the link locks onto
# the first autopilot it hears and ignores frames from elsewhere.
DEFAULT_PX4 = "udpin:127.0.0.1:14540"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("companion", help="drone side: PX4 <-> Zenoh, camera, commands, link-loss failsafe")
    p.add_argument("--id", default="uav1", help="drone id, the namespace of its topics (default uav1)")
    p.add_argument("--px4", default=DEFAULT_PX4,
                   help=f"PX4 MAVLink connection (default {DEFAULT_PX4}, where PX4 SITL sends); "
                        "'sim' starts the built-in simulator")
    p.add_argument("--sysid", type=int, default=1, help="system id of the built-in simulator (with --px4 sim)")
    p.add_argument("--profile", choices=sorted(PROFILES), default="resilient")
    p.add_argument("--config", type=Path, help="QoS YAML overriding streams (setpoint, sensor, state, image, events)")
    p.add_argument("--iface", help="network interface towards the GCS for the multicast transport "
                   "(profiles resilient, resilient_multicast; required by the latter)")
    add_session_arguments(p)
    p.add_argument("--link-keys", metavar="DIR",
                   help="seal every topic sample (ChaCha20-Poly1305, replay window, per-role keys) with this "
                        "node's keyring DIR/<id>.json from `zenoh-robot keys link` (docs/security.md); "
                        "re-read on SIGHUP")
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


def _free_udp_port() -> int:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def run(args: argparse.Namespace) -> int:
    from zenoh_robot.tools.cli.main import CliError
    try:
        validate_node_name(args.id)
    except ValueError as exc:
        raise CliError(f"--id: {exc}") from None
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
    from .mavlink_tunnel import MavlinkTunnel, maybe_tee
    with px4_connection(args.px4, args.sysid) as px4_conn, \
            maybe_tee(args.mavlink_tunnel, px4_conn) as (tee, connection), \
            Px4Link(connection, geofence=in_force.geofence()) as link, \
            Node("companion", namespace=args.id, config=session, executor=MultiThreadedExecutor(3), wire=wire,
                 parameter_overrides=params, enable_topic_statistics=not args.no_topic_statistics) as node:
        log.info("companion %s: PX4 at %s, profile %s", args.id, connection, profile.name)
        if not link.wait_connected(timeout=3.0):
            log.warning("no PX4 heartbeat yet on %s; waiting in the background (the sensor rate is asked "
                        "when PX4 appears)", connection)
        companion = Companion(node, link, config)
        if tee is not None:
            MavlinkTunnel(node, tee, allow_control=args.mavlink_tunnel_allow_control)
        if link.connected:   # else the companion asks on PX4's first heartbeat; px4_link after reconnects
            try:
                companion.telemetry.request_rates()
            except CommandError as exc:   # PX4's default rate applies until it reconnects
                log.warning("could not set the HIGHRES_IMU rate: %s", exc)
            companion.telemetry.request_streams()   # logs what PX4 refused; never raises a CommandError
        spinner = threading.Thread(target=node.spin, name="companion-spin", daemon=True)
        spinner.start()
        try:
            stop.wait(timeout=args.duration)
        except KeyboardInterrupt:
            pass
        finally:
            node.shutdown()
            spinner.join(timeout=2.0)
        summary = companion.summary()
        log.info("%s", summary_line(args.id, connection, summary))
        if args.record:
            write_summary(args.record, summary)
    return 0
