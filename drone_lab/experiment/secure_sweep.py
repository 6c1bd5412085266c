"""Secure and resilient together, measured: the secure profile (mTLS over QUIC or TLS) on a lossy link.

Two small endpoint processes, one per network namespace of :class:`~.netns.LossyLink` (nftables
random drop on both sides of a veth): the drone side publishes a 200 Hz ``SensorCombined`` stream
and listens; the GCS side dials it and publishes a 10 Hz setpoint stream with the resilient
profile's setpoint QoS (history redundancy + 64 deadline-driven repeats). The very same streams run
over each transport profile, so the table compares transports only:

- ``secure-quic`` / ``secure-tls``: ``SessionConfig(secure=...)`` (mTLS against a CA made for the
  run, the role ACL), tuned for loss (:data:`LOSSY_TUNING`); QUIC with ``?mixed_rel=1`` (best
  effort as QUIC datagrams), TLS over TCP (everything on one reliable byte stream);
- ``secure-quic-split``: two such QUIC connections, priorities 0-3 (setpoints) and 4-7 (sensors);
- ``secure-quic-untuned``: the same with Zenoh's defaults (only with loss from start-up: the
  tuning is about forming the session);
- ``plain``: unicast TCP + UDP without TLS, as the lossy-link experiment's plain profiles run.

Per cell: delivered % (unique / sent in the window), mean and p99 age, the longest gap, and the
session set-up time (launch to the first sample at each end). ``--start after`` applies the loss
once the sessions are up, ``--start startup`` from the first packet. Needs root (namespaces).

    python -m drone_lab.experiment.secure_sweep --out /tmp/secure-sweep
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from zenoh_robot.session_config import SessionConfig
from zenoh_robot.tools.stream_metrics import StreamRecorder, analyse

from .netns import LossyLink, NetnsUnavailable, unavailable_reason

MODULE = "drone_lab.experiment.secure_sweep"
PORT = 7447
SENSOR_HZ = 200.0
SETPOINT_HZ = 10.0
# Receivers listen this long after the senders stop: a sample delivered late is delivered (its
# age says how late), a sample never delivered is lost.
DRAIN_S = 1.5
# On a congestion-controlled link (QUIC datagrams) the resilient setpoint QoS's 64 repeats, made
# for raw multicast UDP, fill the congestion window at loss; the lean variant keeps qos.RESILIENT's 3.
LEAN = ("secure-quic-lean",)
LEAN_REPEAT = 3
PROFILES = ("secure-quic", "secure-quic-split", "secure-quic-lean", "secure-tls", "plain", "secure-quic-untuned")
# The default run (36 cells, ~10 min on 2 cores); secure-quic-split on request (--profiles).
DEFAULT_PROFILES = ("secure-quic", "secure-quic-lean", "secure-tls", "plain", "secure-quic-untuned")
LOSSES = (0, 10, 30, 50)
STARTS = ("after", "startup")
# What helps a unicast (handshaking) session live through loss, in Zenoh 1.10 keys (each checked
# against zenoh.Config: an unknown key is an error there). ``connect/retry`` must be set as one
# object: Zenoh rejects ``connect/retry/period_init_ms`` alone ("unknown key").
LOSSY_TUNING: dict[str, Any] = {
    # Dial again soon after a failed attempt (default 1 s, doubling to 4 s): at 30-50 % loss most
    # attempts fail, and the next one should not wait seconds.
    "connect/retry": {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 1.5},
    # Give up on a stuck handshake (lost TLS/QUIC flights) sooner than 10 s and start a fresh one.
    "transport/unicast/open_timeout": 4000,
    # The listener waits as long for the dialler's handshake; our 2 s default would cut slow ones.
    "transport/unicast/accept_timeout": 10000,
    # A 10 s lease with 10 keep-alives per lease: bursts of loss rarely silence a link for 10 s.
    "transport/link/tx/lease": 10000,
    "transport/link/tx/keep_alive": 10,
}


@dataclass(frozen=True)
class SecureCell:
    profile: str
    loss: float
    start: str = "after"
    duration: float = 8.0     # the measurement window, s
    warmup: float = 3.0       # launch to window start, s (sessions form here with --start after)


def make_keys(keys_dir: Path, link: LossyLink) -> None:
    """A CA for the run, the GCS (commanding uav1) and uav1, whose certificate names its veth address."""
    from zenoh_robot.tools import keys
    keys.init_ca(keys_dir)
    keys.issue(keys_dir, "gcs", "gcs", drones=["uav1"], sans=[link.addr("gcs")])
    keys.issue(keys_dir, "uav1", "drone", sans=[link.addr("drone")])


def session_kwargs(profile: str, side: str, link: LossyLink, keys_dir: Path) -> dict[str, Any]:
    """``SessionConfig`` keyword arguments of one side (JSON, handed to the endpoint process)."""
    drone = link.addr("drone")
    base: dict[str, Any] = {"multicast_scouting": False, "shared_memory": False}
    if profile == "plain":
        eps = [f"tcp/{drone}:{PORT}", f"udp/{drone}:{PORT}"]
        return {**base, "listen": eps if side == "drone" else [], "connect": [] if side == "drone" else eps,
                "accept_timeout_s": 10.0}
    # QUIC with mixed reliability (Zenoh >= 1.10 endpoint metadata): best-effort samples go as QUIC
    # datagrams, reliable ones on a stream, one connection and one handshake. Without it every
    # sample rides one reliable stream and waits behind each retransmission (head-of-line blocking).
    if profile == "secure-tls":
        eps = [f"tls/{drone}:{PORT}"]
    elif profile in ("secure-quic-split", "secure-quic-lean"):
        # Two QUIC connections, each with its own congestion window: control, real-time and
        # interactive priorities (setpoints, commands, state) apart from data (sensors, images),
        # so a 200 Hz stream's losses never throttle the setpoints.
        eps = [f"quic/{drone}:{PORT}?prio=0-3;mixed_rel=1", f"quic/{drone}:{PORT + 1}?prio=4-7;mixed_rel=1"]
    else:
        eps = [f"quic/{drone}:{PORT}?mixed_rel=1"]
    kw = {**base, "secure": str(keys_dir), "name": "uav1" if side == "drone" else "gcs", "max_links": len(eps),
          "listen": eps if side == "drone" else [], "connect": [] if side == "drone" else eps}
    if profile != "secure-quic-untuned":
        kw["extra"] = dict(LOSSY_TUNING)
    return kw


# --- the endpoint process ------------------------------------------------------------------------

def endpoint(side: str, config_kw: dict[str, Any], duration: float, out: Path, drain: float = 0.0,
             setpoint_repeat: int | None = None) -> None:
    """Publish for ``duration`` s from now, listen ``drain`` s more; write the records and first-sample times."""
    from drone_contract.streams import stream_profile
    from zenoh_robot import Message, MessageInfo, Node
    from zenoh_robot.msgs import Header, SensorCombined, Setpoint

    qos = dict(stream_profile("resilient").qos)
    if setpoint_repeat is not None:
        qos["setpoint"] = qos["setpoint"].replace(repeat=setpoint_repeat)
    end = time.monotonic() + duration
    sent, received = StreamRecorder(), StreamRecorder()
    first: dict[str, int] = {}
    out_type: type[SensorCombined] | type[Setpoint]
    in_type: type[SensorCombined] | type[Setpoint]
    if side == "drone":
        name, ns, out_type, out_topic, out_qos, rate = "companion", "uav1", SensorCombined, "/uav1/sensor", \
            qos["sensor"], SENSOR_HZ
        in_type, in_topic, in_qos = Setpoint, "/uav1/setpoint", qos["setpoint"]
    else:
        name, ns, out_type, out_topic, out_qos, rate = "gcs", "", Setpoint, "/uav1/setpoint", qos["setpoint"], \
            SETPOINT_HZ
        in_type, in_topic, in_qos = SensorCombined, "/uav1/sensor", qos["sensor"]
    opened = time.time_ns()

    def on_sample(msg: Message, info: MessageInfo) -> None:
        first.setdefault("rx", info.received_stamp_ns)
        received.record(info.seq, info.source_stamp_ns, info.received_stamp_ns)

    with Node(name, namespace=ns, config=SessionConfig(**config_kw)) as node:
        first["open"] = time.time_ns() - opened
        node.create_subscription(in_type, in_topic, on_sample, in_qos)
        pub = node.create_publisher(out_type, out_topic, out_qos)
        threading.Thread(target=node.spin, daemon=True).start()
        period, next_t = 1.0 / rate, time.monotonic()
        while next_t < end:
            info = pub.publish(out_type(header=Header.now()))   # every field but the header keeps its default
            sent.record(info.seq, info.stamp_ns)
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
        time.sleep(drain)   # what is still in flight (a reliable link's retransmissions) counts, late
    out.write_text(json.dumps({"sent": sent.to_dict(), "received": received.to_dict(), "first_rx_ns": first.get("rx"),
                               "open_ns": first.get("open")}))


# --- one cell, a sweep ---------------------------------------------------------------------------

def run_cell(cell: SecureCell, workdir: Path, link: LossyLink, keys_dir: Path) -> dict[str, Any]:
    """One cell on an existing ``link`` (its loss is set here); the result as a JSON-able dict."""
    workdir.mkdir(parents=True, exist_ok=True)
    total = cell.warmup + cell.duration + 1.0
    link.set_loss(cell.loss if cell.start == "startup" else 0.0)
    procs: dict[str, subprocess.Popen[bytes]] = {}
    launch = time.time_ns()
    for side in ("drone", "gcs"):   # the listener first, as a drone is up before its operator
        kw = json.dumps(session_kwargs(cell.profile, side, link, keys_dir))
        cmd = [sys.executable, "-m", MODULE, "endpoint", "--side", side, "--config", kw, "--duration", str(total),
               "--drain", str(DRAIN_S), "--out", str(workdir / f"{side}.json")]
        if cell.profile in LEAN:
            cmd += ["--setpoint-repeat", str(LEAN_REPEAT)]
        with open(workdir / f"{side}.log", "w") as log:
            procs[side] = subprocess.Popen(link.exec_in(side) + cmd, stdout=log, stderr=subprocess.STDOUT)
    try:
        time.sleep(cell.warmup)
        if cell.start == "after":
            link.set_loss(cell.loss)
        t0 = time.time_ns()
        time.sleep(cell.duration)
        t1 = time.time_ns()
        link.set_loss(0)
        for p in procs.values():
            p.wait(timeout=total + DRAIN_S + 30)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    return analyse_cell(cell, workdir, launch, t0, t1, {k: p.returncode for k, p in procs.items()})


def analyse_cell(cell: SecureCell, workdir: Path, launch: int, t0: int, t1: int,
                 exit_codes: dict[str, int | None]) -> dict[str, Any]:
    result: dict[str, Any] = {**asdict(cell), "exit_codes": exit_codes, "topics": {}}
    try:
        d = json.loads((workdir / "drone.json").read_text())
        g = json.loads((workdir / "gcs.json").read_text())
    except (OSError, ValueError):
        result["error"] = f"missing records (see {workdir}/*.log)"
        return result
    for topic, rx, tx in (("setpoint", d, g), ("sensor", g, d)):
        s = analyse(StreamRecorder.from_dict(rx["received"]), StreamRecorder.from_dict(tx["sent"]), t0, t1).as_dict()
        s["setup_s"] = (rx["first_rx_ns"] - launch) / 1e9 if rx["first_rx_ns"] else None
        result["topics"][topic] = s
    return result


def run_sweep(out_dir: Path, cells: list[SecureCell], log: Any = print) -> list[dict[str, Any]]:
    out_dir.mkdir(parents=True, exist_ok=True)
    results: list[dict[str, Any]] = []
    with LossyLink() as link, tempfile.TemporaryDirectory(prefix="zr-keys-") as tmp:
        keys_dir = Path(tmp)
        make_keys(keys_dir, link)
        for cell in cells:
            workdir = out_dir / "cells" / f"{cell.start}-{cell.profile}-{cell.loss:g}"
            try:
                r = run_cell(cell, workdir, link, keys_dir)
            except Exception as exc:   # one broken cell must not lose the sweep
                r = {**asdict(cell), "error": f"{type(exc).__name__}: {exc}", "topics": {}}
            results.append(r)
            with (out_dir / "results.jsonl").open("a") as f:
                f.write(json.dumps(r) + "\n")
            log(one_line(r))
    return results


def _num(v: object, fmt: str, unit: str = "") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:{fmt}}{unit}"


def one_line(r: dict[str, Any]) -> str:
    head = f"{r['profile']:19s} {r['loss']:3g}% ({r['start']:7s})"
    if r.get("error"):
        return f"{head}: ERROR {r['error']}"
    return head + " | " + " | ".join(
        f"{t} {_num(s.get('delivered_pct'), '5.1f', '%')} age {_num(s.get('age_avg_ms'), '.0f')}/"
        f"{_num(s.get('age_p99_ms'), '.0f')} ms gap {_num(s.get('longest_gap_ms'), '.0f')} ms "
        f"setup {_num(s.get('setup_s'), '.1f', ' s')}" for t, s in r["topics"].items())


def markdown(results: list[dict[str, Any]]) -> str:
    rows = ["| loss from | profile | loss % | setpoint delivered | setpoint age mean / p99 | setpoint max gap "
            "| sensor delivered | sensor age mean / p99 | sensor max gap | set-up (first setpoint / sensor) |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        if r.get("error"):
            rows.append(f"| {r['start']} | {r['profile']} | {r['loss']:g} | error: {r['error']} |||||||")
            continue
        sp, se = r["topics"]["setpoint"], r["topics"]["sensor"]

        def ms(v: float | None) -> str:
            return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else (
                f"{v / 1000:.1f} s" if v >= 1000 else f"{v:.0f} ms")
        rows.append(f"| {r['start']} | {r['profile']} | {r['loss']:g} | {_num(sp['delivered_pct'], '.1f', ' %')} "
                    f"| {ms(sp['age_avg_ms'])} / {ms(sp['age_p99_ms'])} | {ms(sp['longest_gap_ms'])} "
                    f"| {_num(se['delivered_pct'], '.1f', ' %')} | {ms(se['age_avg_ms'])} / {ms(se['age_p99_ms'])} "
                    f"| {ms(se['longest_gap_ms'])} | {_num(sp['setup_s'], '.1f', ' s')} / "
                    f"{_num(se['setup_s'], '.1f', ' s')} |")
    return "\n".join(rows) + "\n"


# --- sealed resilient beside plain resilient, through cell.py's flying cells ----------------------

LINK_KEYS_ENV = "ZR_LINK_KEYS"     # the companion's and the GCS's --link-keys default (their CLIs read it)
SEALED_LOSSES = (0, 30, 50, 70, 90)
CELL_PROBE_ID = "cell-probe"       # the GCS id of cell.py's command probe through a router (`gcs cmd`)


def make_cell_link_keys(keys_dir: Path) -> Path:
    """Link keyrings for a cell's apps: uav1, the GCS under its default id (cell.py passes none) and the
    router cell's command probe; returns the directory the apps' ``--link-keys`` takes."""
    from gcs.config import default_client_id
    from zenoh_robot.tools import keys
    keys.make_link_keys(keys_dir, gcs={default_client_id(): ["uav1"], CELL_PROBE_ID: ["uav1"]})
    return keys_dir / keys.LINK_DIR


def cell_options(pairs: list[str]) -> dict[str, Any]:
    """``NAME=VALUE`` cell options, typed by ``cell.CellSpec``'s fields (whatever that version has)."""
    from .cell import CellSpec
    fields = {f.name: f for f in dataclasses.fields(CellSpec)}
    options: dict[str, Any] = {}
    for pair in pairs:
        name, _, raw = pair.partition("=")
        if name not in fields or name in ("profile", "loss"):
            known = ", ".join(sorted(set(fields) - {"profile", "loss"}))
            raise ValueError(f"cell option {name!r}: CellSpec has {known}")
        default = fields[name].default
        options[name] = type(default)(raw) if isinstance(default, (int, float)) and not isinstance(default, bool) \
            else raw
    return options


@contextmanager
def _env(name: str, value: str | None) -> Iterator[None]:
    before = os.environ.get(name)
    if value is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = before


def protection_of(workdir: Path) -> dict[str, bool]:
    """Per app, whether its start-up line says its samples were sealed (the row's proof of what ran)."""
    out = {}
    for side in ("gcs", "drone"):
        try:
            text = (workdir / f"{side}.log").read_text(errors="replace")
        except OSError:
            text = ""
        out[side] = "link protection: per-sample AEAD" in text
    return out


def run_sealed_cell(loss: float, sealed: bool, options: dict[str, Any], out_dir: Path,
                    link_keys: Path) -> dict[str, Any]:
    """One resilient cell of ``cell.py`` (its flying cell, whatever it does now), sealed or not."""
    from .cell import CellSpec, run_cell
    spec = CellSpec("resilient", float(loss), **options)
    kind = "sealed" if sealed else "plain"
    workdir = out_dir / "cells" / f"{spec.start}-{kind}-{spec.label}-{loss:g}-r{options.get('run', 0)}"
    with _env(LINK_KEYS_ENV, str(link_keys) if sealed else None):
        result = run_cell(spec, workdir)
    result["sealed"] = sealed
    result["protection"] = protection_of(workdir)
    result["row"] = f"{spec.label}{'+sealed' if sealed else ''}"
    if sealed and not all(result["protection"].values()):
        result["error"] = f"an app ran unsealed: {result['protection']} (see {workdir}/*.log)"
    return result


def run_sealed_sweep(out_dir: Path, losses: list[float], options: dict[str, Any], runs: int = 1,
                     log: Any = print) -> list[dict[str, Any]]:
    """Per loss and run, the sealed and the plain resilient cell back to back (order alternating),
    one line each to ``sealed.jsonl`` as it finishes."""
    out_dir.mkdir(parents=True, exist_ok=True)
    results: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="zr-link-keys-") as tmp:
        link_keys = make_cell_link_keys(Path(tmp))
        n = 0
        for run in range(runs):
            for loss in losses:
                order = (True, False) if n % 2 == 0 else (False, True)
                n += 1
                for sealed in order:
                    opts = {**options, "run": run} if "run" in {f.name for f in _cell_fields()} else dict(options)
                    try:
                        r = run_sealed_cell(loss, sealed, opts, out_dir, link_keys)
                    except Exception as exc:   # one broken cell must not lose the sweep
                        r = {"loss": loss, "sealed": sealed, "row": "resilient" + ("+sealed" if sealed else ""),
                             "error": f"{type(exc).__name__}: {exc}", "topics": {}}
                    results.append(r)
                    with (out_dir / "sealed.jsonl").open("a") as f:
                        f.write(json.dumps(r) + "\n")
                    log(sealed_line(r))
    return results


def _cell_fields() -> tuple[dataclasses.Field[Any], ...]:
    from .cell import CellSpec
    return dataclasses.fields(CellSpec)


def _fps(r: dict[str, Any]) -> float | None:
    whole = r.get("topics", {}).get("image_whole") or {}
    v = whole.get("rate_hz")
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def sealed_line(r: dict[str, Any]) -> str:
    head = f"{r['row']:22s} {r['loss']:3g}%"
    if r.get("error"):
        return f"{head}: ERROR {r['error']}"
    t = r["topics"]
    bw = r.get("bandwidth_kBps") or {}
    return (f"{head} | setpoint {_num(t['setpoint']['delivered_pct'], '5.1f', '%')} gap "
            f"{_num(t['setpoint']['longest_gap_ms'], '.0f')} ms | sensor "
            f"{_num(t['sensor']['delivered_pct'], '5.1f', '%')}"
            f" | image {_num(_fps(r), '.1f')} fps whole | kB/s gcs {_num(bw.get('gcs'), '.1f')} drone "
            f"{_num(bw.get('drone'), '.1f')}" + ("" if r.get("offboard_kept") is None else
                                                f" | offboard {'kept' if r['offboard_kept'] else 'LOST'}"))


def sealed_markdown(results: list[dict[str, Any]]) -> str:
    """One row per (loss, sealed): median over runs, the range in brackets when runs > 1."""
    rows = ["| loss % | profile | runs | setpoint delivered | setpoint longest gap | offboard kept | sensor delivered "
            "| image fps (whole frames) | fresh strips | kB/s GCS -> drone | kB/s drone -> GCS |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    groups: dict[tuple[float, str], list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault((float(r["loss"]), r["row"]), []).append(r)

    def cell(rs: list[dict[str, Any]], get: Any, fmt: str, unit: str = "") -> str:
        xs = [v for v in (get(r) for r in rs if not r.get("error")) if v is not None and not
              (isinstance(v, float) and math.isnan(v))]
        if not xs:
            return "-"
        m = statistics.median(xs)
        return f"{m:{fmt}}{unit}" + (f" ({min(xs):{fmt}}-{max(xs):{fmt}})" if len(xs) > 1 else "")

    for (loss, row), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], "+sealed" in kv[0][1], kv[0][1])):
        errors = [r["error"] for r in rs if r.get("error")]
        ok = [r for r in rs if not r.get("error")]
        kept = [bool(r["offboard_kept"]) for r in ok if r.get("offboard_kept") is not None]
        rows.append(
            f"| {loss:g} | {row} | {len(ok)}{f' ({len(errors)} failed)' if errors else ''} "
            f"| {cell(ok, lambda r: r['topics']['setpoint']['delivered_pct'], '.1f', ' %')} "
            f"| {cell(ok, lambda r: r['topics']['setpoint']['longest_gap_ms'], '.0f', ' ms')} "
            f"| {f'{sum(kept)}/{len(kept)}' if kept else '-'} "
            f"| {cell(ok, lambda r: r['topics']['sensor']['delivered_pct'], '.1f', ' %')} "
            f"| {cell(ok, _fps, '.1f')} "
            f"| {cell(ok, lambda r: r['topics'].get('image_strip', {}).get('delivered_pct'), '.1f', ' %')} "
            f"| {cell(ok, lambda r: (r.get('bandwidth_kBps') or {}).get('gcs'), '.1f')} "
            f"| {cell(ok, lambda r: (r.get('bandwidth_kBps') or {}).get('drone'), '.1f')} |")
    return "\n".join(rows) + "\n"


def sealed_main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"python -m {MODULE} sealed",
                                description="the sealed resilient profile (--link-keys) beside plain resilient "
                                            "through cell.py's cells, at each loss, same run")
    p.add_argument("--out", type=Path, default=Path("secure-lossy"), help="results directory (raw jsonl, table)")
    p.add_argument("--losses", default=",".join(str(x) for x in SEALED_LOSSES), help="loss %% per direction")
    p.add_argument("--runs", type=int, default=1, help="runs per cell (median and range in the table)")
    p.add_argument("--cell", action="append", default=[], metavar="NAME=VALUE",
                   help="a cell.CellSpec option, e.g. duration=20, loss_model=bursty, transport=router; repeatable")
    p.add_argument("--report-only", action="store_true", help="redraw the table from OUT/sealed.jsonl")
    args = p.parse_args(argv)
    if args.report_only:
        results = [json.loads(x) for x in (args.out / "sealed.jsonl").read_text().splitlines() if x.strip()]
    else:
        reason = unavailable_reason()
        if reason:
            print(f"secure_sweep sealed: {reason}", file=sys.stderr)
            return 2
        try:
            options = cell_options(args.cell)
        except ValueError as exc:
            print(f"secure_sweep sealed: {exc}", file=sys.stderr)
            return 2
        results = run_sealed_sweep(args.out, [float(x) for x in args.losses.split(",")], options, args.runs)
    table = sealed_markdown(results)
    (args.out / "sealed.md").write_text(table)
    print(table)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m drone_lab.experiment.secure_sweep", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd")
    e = sub.add_parser("endpoint", help="(internal) one side of a cell, run inside its namespace")
    e.add_argument("--side", choices=("gcs", "drone"), required=True)
    e.add_argument("--config", required=True, help="SessionConfig keyword arguments as JSON")
    e.add_argument("--duration", type=float, required=True)
    e.add_argument("--out", type=Path, required=True)
    e.add_argument("--drain", type=float, default=0.0, help="listen this long after the last publish, s")
    e.add_argument("--setpoint-repeat", type=int, default=None, help="override the setpoint QoS's repeat count")
    p.add_argument("--out", type=Path, default=Path("secure-sweep"), help="results directory")
    p.add_argument("--profiles", default=",".join(DEFAULT_PROFILES), help=f"any of {', '.join(PROFILES)}")
    p.add_argument("--losses", default=",".join(str(x) for x in LOSSES), help="loss %% per direction, e.g. 0,30")
    p.add_argument("--starts", default=",".join(STARTS), help="after (loss once up), startup (loss from the start)")
    p.add_argument("--duration", type=float, default=8.0, help="measurement window per cell, s")
    p.add_argument("--warmup", type=float, default=3.0, help="launch to window start, s")
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["sealed"]:
        return sealed_main(argv[1:])
    args = p.parse_args(argv)
    if args.cmd == "endpoint":
        endpoint(args.side, json.loads(args.config), args.duration, args.out, args.drain, args.setpoint_repeat)
        return 0
    reason = unavailable_reason()
    if reason:
        print(f"secure_sweep: {reason}", file=sys.stderr)
        return 2
    unknown = set(args.profiles.split(",")) - set(PROFILES)
    if unknown:
        print(f"secure_sweep: unknown profile(s) {', '.join(sorted(unknown))}; choose from {', '.join(PROFILES)}",
              file=sys.stderr)
        return 2
    cells = [SecureCell(prof, float(loss), start, args.duration, args.warmup)
             for start in args.starts.split(",") for prof in args.profiles.split(",")
             for loss in args.losses.split(",")
             if not (prof == "secure-quic-untuned" and start == "after")]   # its tuning only matters at start-up
    started = time.monotonic()
    try:
        results = run_sweep(args.out, cells)
    except NetnsUnavailable as exc:
        print(f"secure_sweep: {exc}", file=sys.stderr)
        return 2
    table = markdown(results)
    (args.out / "table.md").write_text(table)
    print(table)
    print(f"{len(cells)} cells in {time.monotonic() - started:.0f} s; results in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
