"""``zenoh-robot doctor [--report]``: is this machine ready to talk to the others? (ros2 doctor)

One verdict line per check, ``ok``/``warn``/``fail``; the command exits 1 when any check
fails. Checks: the Zenoh session opens (its zid); its links and peers; other zenoh-robot
nodes seen through the graph (multicast scouting or the configured endpoints reach them);
the clock offset to each publishing node, from the source stamps of a moment of their
samples against the receive time (one-way: offset and latency together; "not measured"
without samples); the interfaces' MTU against the batch size UDP links send; shared memory;
the domain. ``--report`` adds the platform, the session config and the graph.
"""
from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zenoh_robot.session_args import add_session_arguments

from .common import HIDDEN_PREFIX, cli_node, quiet_exit, session_config
from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.node import Node
    from zenoh_robot.session_config import SessionConfig

ZENOH_DEFAULT_BATCH = 65535      # Zenoh 1.10's transport/link/tx/batch_size default
UDP_IP_HEADERS = 28              # IPv4 + UDP header bytes inside the MTU
CLOCK_WARN_MS = 50.0             # a larger one-way offset skews ages, deadlines and lifespans
MAX_CLOCK_TOPICS = 8             # topics sampled for the clock check
CLOCK_LISTEN_S = 1.5
NET = Path("/sys/class/net")


@dataclass(frozen=True)
class Check:
    name: str
    verdict: str        # ok | warn | fail
    detail: str

    def line(self) -> str:
        return f"{self.verdict.upper():4} {self.name}: {self.detail}"


def _plugins() -> list[Any]:
    """Installed packages' checks (entry point group ``zenoh_robot.doctor``: a module with
    ``register(parser)`` and ``checks(args) -> [(name, verdict, detail)]``), e.g. px4_link's flight
    controller link: the doctor itself knows no MAVLink. A broken plugin is skipped, not fatal."""
    found = []
    for ep in sorted(entry_points(group="zenoh_robot.doctor"), key=lambda e: e.name):
        try:
            found.append(ep.load())
        except (ImportError, AttributeError):
            continue
    return found


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("doctor", help="check the Zenoh session, peers, clocks, MTU, shared memory and domain "
                                      "(and, with --px4, the flight controller's link)")
    add_session_arguments(p)
    p.add_argument("--report", "-r", action="store_true", help="also print platform, session config and graph")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to learn the graph (default 2)")
    p.add_argument("--no-clock", action="store_true", help="skip sampling topics for the clock offset")
    plugins = _plugins()
    for plugin in plugins:
        plugin.register(p)
    p.set_defaults(func=run, doctor_plugins=plugins)


@quiet_exit
def run(args: argparse.Namespace) -> int:
    path = getattr(args, "zenoh", None)
    try:
        config = session_config(args)
    except CliError as exc:
        print(Check("session", "fail", f"config: {exc}").line())
        return 1
    checks: list[Check] = []
    try:
        with cli_node("doctor", args) as node:
            checks.append(Check("session", "ok", f"opened, zid {node.zid}, mode {config.mode}"))
            checks += _peers(node)
            checks.append(_graph(node, args.timeout))
            checks += [Check("clock", "ok", "not measured (--no-clock)")] if args.no_clock else _clock(node)
            checks += _mtu(node, config)
            checks.append(_shm(node, config))
            checks.append(Check("domain", "ok", _domain_text(config)))
            for check in checks:
                print(check.line(), flush=True)
            if args.report:
                _report(node, config, path)
    except CliError as exc:
        checks.append(Check("session", "fail", f"cannot open: {exc}"))
        print(checks[-1].line())
    for plugin in args.doctor_plugins:
        for name, verdict, detail in plugin.checks(args):
            checks.append(Check(name, verdict, detail))
            print(checks[-1].line(), flush=True)
    fails = sum(c.verdict == "fail" for c in checks)
    warns = sum(c.verdict == "warn" for c in checks)
    print(f"{len(checks)} checks: {len(checks) - fails - warns} ok, {warns} warn, {fails} fail")
    return 1 if fails else 0


# -- checks ------------------------------------------------------------------------------------
def _peers(node: "Node") -> list[Check]:
    info = node.session.info
    peers, routers = list(info.peers_zid()), list(info.routers_zid())
    links = list(info.links())
    if not peers and not routers:
        return [Check("peers", "warn", "no Zenoh peer or router connected (alone on the network?)")]
    protos = sorted({str(link.src).split("/", 1)[0] for link in links})
    return [Check("peers", "ok", f"{len(peers)} peer(s), {len(routers)} router(s), {len(links)} link(s) "
                                 f"({', '.join(protos) or 'none'})")]


def _graph(node: "Node", timeout: float) -> Check:
    from .node import node_names
    from .topic import discover_graph

    discover_graph(node, timeout)
    names = node_names(node, show_all=False)
    if not names:
        return Check("discovery", "warn", "no other zenoh-robot node seen (scouting or endpoints reach none, "
                                          "or none is running)")
    shown = ", ".join(names[:5]) + (f", ... ({len(names)})" if len(names) > 5 else "")
    return Check("discovery", "ok", f"{len(names)} node(s) seen: {shown}")


def _clock(node: "Node") -> list[Check]:
    """Median (receive - source stamp) per publishing node, from a moment of its samples."""
    from zenoh_robot.graph import EndpointType

    from .reader import adapted_qos

    pubs = [e for e in node.graph.endpoints(kind=EndpointType.PUBLISHER)
            if not e.node_name.startswith(HIDDEN_PREFIX) and e.zid != node.zid]
    who = {e.endpoint_gid: f"{e.node_namespace.rstrip('/')}/{e.node_name}" for e in pubs}
    topics = sorted({e.topic_name for e in pubs})[:MAX_CLOCK_TOPICS]
    if not topics:
        return [Check("clock", "ok", "not measured (no remote publisher to sample)")]
    ages: dict[str, list[float]] = {}

    def on_sample(_raw: Any, info: Any) -> None:
        if info.source_stamp_ns > 0 and len(ages.setdefault(who.get(info.publisher_id, "?"), [])) < 1000:
            ages[who.get(info.publisher_id, "?")].append(info.age_ms)

    subs = [node.create_subscription(None, t, on_sample, adapted_qos([e for e in pubs if e.topic_name == t]),
                                     raw=True) for t in topics]
    end = time.monotonic() + CLOCK_LISTEN_S
    while time.monotonic() < end:
        node.spin_once(0.05)
    for sub in subs:
        node.destroy_subscription(sub)
    ages.pop("?", None)
    if not ages:
        return [Check("clock", "ok", f"not measured (no sample on {len(topics)} topic(s) within "
                                     f"{CLOCK_LISTEN_S:g} s)")]
    out = []
    for name, values in sorted(ages.items()):
        offset = statistics.median(values)
        verdict = "ok" if abs(offset) < CLOCK_WARN_MS else "warn"
        out.append(Check("clock", verdict, f"{name}: {offset:+.1f} ms (median receive - source stamp over "
                                           f"{len(values)} samples; offset and latency together)"))
    return out


def interface_mtus() -> dict[str, int]:
    out: dict[str, int] = {}
    for entry in sorted(NET.glob("*/mtu")) if NET.is_dir() else []:
        try:
            out[entry.parent.name] = int(entry.read_text().strip())
        except (OSError, ValueError):
            continue
    return out


def batch_size(config: "SessionConfig") -> int:
    """The batch size the session sends: the config's, else its file's (SessionConfig.from_file keeps
    only mode, endpoints and scouting), else Zenoh's default."""
    if config.batch_size:
        return config.batch_size
    if config.source:
        import json

        import zenoh
        try:
            value = json.loads(zenoh.Config.from_file(config.source).get_json("transport/link/tx/batch_size"))
            if isinstance(value, int) and value > 0:
                return value
        except Exception:    # unreadable here means Zenoh's default there
            pass
    return ZENOH_DEFAULT_BATCH


def _mtu(node: "Node", config: "SessionConfig") -> list[Check]:
    mtus = interface_mtus()
    if not mtus:
        return [Check("mtu", "ok", "not measured (no /sys/class/net)")]
    batch = batch_size(config)
    udp_ifaces = sorted({iface for link in node.session.info.links() if str(link.src).startswith("udp/")
                         for iface in link.interfaces if iface in mtus and iface != "lo"})
    listens_udp = config.uses_udp()
    shown = ", ".join(f"{k} {v}" for k, v in mtus.items())
    too_small = [i for i in udp_ifaces if batch > mtus[i] - UDP_IP_HEADERS]
    if too_small:
        worst = min(mtus[i] for i in too_small)
        return [Check("mtu", "warn", f"UDP batches up to {batch} bytes over {', '.join(too_small)} (MTU {worst}) "
                                     f"go as IP fragments, and one lost fragment loses the batch: set batch_size "
                                     f"<= {worst - UDP_IP_HEADERS} (SessionConfig.batch_size); interfaces: {shown}")]
    where = "UDP links fit" if udp_ifaces else ("no UDP link up yet" if listens_udp else "no UDP endpoint")
    return [Check("mtu", "ok", f"batch size {batch} bytes, {where}; interfaces: {shown}")]


def _shm(node: "Node", config: "SessionConfig") -> Check:
    wanted = config.shared_memory_enabled
    # eclipse-zenoh's stubs omit Transport.is_shm, which its shared-memory builds have.
    used = len([t for t in node.session.info.transports() if t.is_shm])   # type: ignore[attr-defined]
    text = f"{'on' if wanted else 'off'} in the config, {used} transport(s) using it"
    if wanted and config.secure is not None:   # unreachable by SessionConfig's rules; kept as a guard
        return Check("shared memory", "fail", text + ": a secure session must not hand payloads to local processes")
    return Check("shared memory", "ok", text)


def _domain_text(config: "SessionConfig") -> str:
    if not config.domain:
        return "0 (keys unprefixed; ZR_DOMAIN or the config's domain sets another)"
    return f"{config.domain} (every key under Zenoh namespace zr{config.domain})"


# -- --report -----------------------------------------------------------------------------------
def _report(node: "Node", config: "SessionConfig", path: str | None) -> None:
    from importlib.metadata import PackageNotFoundError, version

    def ver(pkg: str) -> str:
        try:
            return version(pkg)
        except PackageNotFoundError:
            return "not installed"

    def section(title: str, rows: list[tuple[str, Any]]) -> None:
        print(f"\n   {title}")
        for k, v in rows:
            print(f"{k:>24} : {v}")

    section("PLATFORM INFORMATION", [("system", platform.system()), ("platform", platform.platform()),
                                     ("python", sys.version.split()[0]), ("zenoh-robot", ver("zenoh-robot")),
                                     ("eclipse-zenoh", ver("eclipse-zenoh")), ("pymavlink", ver("pymavlink"))])
    section("SESSION", [("config file", path or "(defaults)"), ("mode", config.mode),
                        ("listen", ", ".join(config.listen) or "-"), ("connect", ", ".join(config.connect) or "-"),
                        ("multicast scouting", config.multicast_scouting),
                        ("batch size", batch_size(config)),
                        ("secure", config.secure or "no"), ("zid", node.zid)])
    links = list(node.session.info.links())
    section("LINKS", [(str(link.zid)[:12], f"{link.src} -> {link.dst} mtu {link.mtu} "
                                          f"{','.join(link.interfaces) or '-'}") for link in links] or [("-", "none")])
    section("NETWORK INTERFACES", [(k, f"mtu {v}") for k, v in interface_mtus().items()])
    from .node import node_names
    section("NODES", [(str(i + 1), n) for i, n in enumerate(node_names(node, show_all=False))] or [("-", "none")])
    topics = [(name, ", ".join(types)) for name, types in node.get_topic_names_and_types()]
    section("TOPICS", topics or [("-", "none")])
