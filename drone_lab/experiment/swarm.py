"""Swarm scaling sweep: one GCS and N drones (each with its own simulator), peer mode or via a router.

Every cell runs real processes on loopback only: ``zenoh-robot router`` (router mode), the
GCS (``python -m gcs``, no dashboard) and N companions (``python -m companion --px4 sim``: a
simulator per drone, its own sysid and UDP port). Peer mode: the GCS listens on loopback TCP+UDP
and every companion connects to it (no multicast scouting, so a sweep never meets another system
on the machine). Router mode: everyone is a client of the router.

A flying cell (``fly``, the default) runs the GCS with ``--mission``: every drone arms, climbs,
flies the pattern from its own formation slot (``grid``) for ``duration`` s and lands. Its window
is the pattern's (the GCS's mission record), and per drone it reports the mission's outcome, the
path error against the drone's own slot path (mean, max), the time in OFFBOARD over the time
asked, the commands (success, latency) and the companion's HOLDs. A hovering cell (``fly=False``,
how the sweep ran before issue #29) streams setpoints that the grounded companions ignore.

Figures over the measured window, from the processes' own raw records (exact sequence
numbers joined sender-to-receiver, as the lossy-link experiment does): per drone the
setpoint rate and delivered %, sensor and state delivered %, image fps and age; per
process the CPU share of one core (from /proc, sampled every second) and resident memory.
Each cell's directory keeps the raw records and ``runner.json`` (what the runner measured), so
``reanalyse`` rebuilds every result from them.

This module only starts processes; it never imports the drone system (tools layer).
"""
from __future__ import annotations

import gzip
import json
import os
import secrets
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from zenoh_robot.tools.stream_metrics import StreamRecorder, analyse

ZENOH_ROBOT = [sys.executable, "-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())"]
DRONE_SENSOR_HZ = 200.0    # what a companion asks of PX4 unless its GCS asks otherwise (companion --sensor-rate)
DRONE_CAMERA_FPS = 30.0    # likewise its camera (companion --camera-rate)
# The swarm sweep's and launch files' downlink: 50 Hz of IMU is five samples per 10 Hz setpoint, more than
# a 4 Hz dashboard or a flight log of a hover needs; 15 fps is fluid for an operator and halves the image
# shares, the GCS's largest receive cost per drone (docs/swarm.md).
SWARM_SENSOR_HZ = 50.0
SWARM_CAMERA_FPS = 15.0
CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
LAUNCH_GAP_S = 0.3          # between two process launches in a cell
ROUTER_GAP_S = 1.0          # after the router, before its clients
# A flying cell's time around the pattern: connect, PX4's pre-arm warm-up (up to 30 s), climb (up to
# 30 s), land (up to 40 s): the mission's own bounds (gcs/mission.py), so a companion outlives its GCS.
MISSION_MARGIN_S = 110.0
CPU_SAMPLE_S = 1.0
CORES = os.cpu_count() or 1


@dataclass(frozen=True)
class SwarmCell:
    drones: int
    mode: str = "router"        # router | peer
    camera: bool = True
    duration: float = 15.0
    warmup: float = 8.0
    profile: str = "resilient"
    # Downlink the GCS asks of each drone (gcs --sensor-rate/--camera-rate); None: the drone's own (200 Hz, 30 fps).
    sensor_rate: float | None = None
    camera_rate: float | None = None
    # Flying (gcs --mission): arm, climb, fly the pattern in formation for `duration` s, land.
    fly: bool = False
    pattern: str = "square"
    formation: str = "grid"
    spacing: float = 5.0
    size: float = 4.0
    run: int = 1

    @property
    def name(self) -> str:
        rates = "" if self.sensor_rate is None and self.camera_rate is None else \
            f"_s{self.sensor_rate or 0:g}c{self.camera_rate or 0:g}"
        flight = f"_fly_{self.pattern}_{self.formation}_r{self.run}" if self.fly else ""
        return f"n{self.drones}_{self.mode}_{'cam' if self.camera else 'nocam'}{rates}{flight}"


def _free_port() -> int:
    with socket.socket() as t, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        t.bind(("127.0.0.1", 0))
        port = int(t.getsockname()[1])
        u.bind(("127.0.0.1", port))
        return port


def _config(mode: str, listen: list[str], connect: list[str]) -> dict[str, Any]:
    return {"mode": mode, "listen": {"endpoints": listen}, "connect": {"endpoints": connect},
            "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": mode == "peer"}},
            "transport": {"unicast": {"max_links": 2}, "shared_memory": {"enabled": False}}}


def cell_endpoints(port: int) -> list[str]:
    """Where a cell's GCS or router listens and the others connect. TCP only: a UDP link beside it can carry a
    transport's first declarations, and one lost there hides an entity for the link's life (docs/architecture.md,
    "UDP only where asked for"); on one host UDP buys nothing."""
    return [f"tcp/127.0.0.1:{port}"]


def cpu_ticks(pid: int) -> int | None:
    """utime + stime of a process and its waited children, in clock ticks (None once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return int(fields[11]) + int(fields[12])


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def run_cell(cell: SwarmCell, workdir: Path) -> dict[str, Any]:
    """Run one cell; its processes' logs, records and ``runner.json`` stay in ``workdir``."""
    workdir.mkdir(parents=True, exist_ok=True)
    prefix = f"sw{secrets.token_hex(2)}"
    ids = [f"{prefix}_{i + 1}" for i in range(cell.drones)]
    port = _free_port()
    endpoints = cell_endpoints(port)
    if cell.mode == "router":
        gcs_conf, drone_conf = _config("client", [], endpoints), _config("client", [], endpoints)
    elif cell.mode == "peer":
        gcs_conf, drone_conf = _config("peer", endpoints, []), _config("peer", [], endpoints)
    else:
        raise ValueError(f"mode must be router or peer, got {cell.mode!r}")
    (workdir / "gcs.json5").write_text(json.dumps(gcs_conf))
    (workdir / "drone.json5").write_text(json.dumps(drone_conf))
    # Processes start one after another (LAUNCH_GAP_S apart) and each runs for its own duration: every
    # one must outlive the window, which opens after the last has started, so each gets the whole stagger.
    stagger = ROUTER_GAP_S + LAUNCH_GAP_S * (len(ids) + 1)
    total = cell.warmup + cell.duration + 2.0 + stagger + (MISSION_MARGIN_S if cell.fly else 0.0)
    cmds: dict[str, list[str]] = {}
    if cell.mode == "router":
        cmds["router"] = ZENOH_ROBOT + ["router", "--no-scouting", "--status", "0", "--duration", str(total + 8),
                                        *sum((["--listen", e] for e in endpoints), [])]
    for i, d in enumerate(ids):
        cmds[d] = [sys.executable, "-m", "companion", "--id", d, "--px4", "sim", "--sysid", str(i + 1),
                   "--zenoh", str(workdir / "drone.json5"), "--profile", cell.profile, "--duration", str(total),
                   "--camera", "test" if cell.camera else "none", "--record", str(workdir / f"{d}.json")]
    if cell.fly:   # the pattern's time is the mission's; the GCS ends with it
        flight = ["--mission", "--pattern", cell.pattern, "--formation", cell.formation, "--spacing",
                  f"{cell.spacing:g}", "--size", f"{cell.size:g}", "--duration", f"{cell.duration:g}"]
    else:
        flight = ["--pattern", "hover", "--duration", str(total)]
    cmds["gcs"] = [sys.executable, "-m", "gcs", "--drones", ",".join(ids), "--no-dashboard", *flight,
                   "--zenoh", str(workdir / "gcs.json5"), "--profile", cell.profile,
                   "--record", str(workdir / "gcs.json"), "--gcs-id", f"{prefix}_gcs"]
    if cell.sensor_rate is not None:
        cmds["gcs"] += ["--sensor-rate", f"{cell.sensor_rate:g}"]
    if cell.camera_rate is not None:
        cmds["gcs"] += ["--camera-rate", f"{cell.camera_rate:g}"]
    order = (["router"] if cell.mode == "router" else ["gcs"]) + ids + (["gcs"] if cell.mode == "router" else [])
    procs: dict[str, subprocess.Popen[bytes]] = {}
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    series: list[tuple[int, dict[str, int | None]]] = []   # (time ns, CPU ticks per process)
    try:
        for name in order:
            log = open(workdir / f"{name}.log", "w")
            procs[name] = subprocess.Popen(cmds[name], stdout=log, stderr=subprocess.STDOUT, env=env)
            time.sleep(LAUNCH_GAP_S if name != "router" else ROUTER_GAP_S)
        started_ns = time.time_ns()
        rss: dict[str, float] = {}
        # Hover: a fixed window after the warm-up. Fly: until the GCS's mission ends (its own bounds).
        end = time.monotonic() + (cell.warmup + cell.duration if not cell.fly else total)
        while time.monotonic() < end and (not cell.fly or procs["gcs"].poll() is None):
            series.append((time.time_ns(), {n: cpu_ticks(p.pid) for n, p in procs.items()}))
            if cell.fly or time.monotonic() > end - cell.duration / 2:   # mid-window (hover), mid-flight (fly)
                rss = {n: rss_mb(p.pid) for n, p in procs.items() if p.poll() is None} or rss
            time.sleep(CPU_SAMPLE_S)
        series.append((time.time_ns(), {n: cpu_ticks(p.pid) for n, p in procs.items()}))
        _stop(procs, ["gcs"], total + 30 if not cell.fly else 60)
        # Companions write their records on SIGTERM (a flying cell's outlive the mission on purpose).
        _stop(procs, ids, 0 if cell.fly else total + 30, terminate=cell.fly)
        if "router" in procs:
            _stop(procs, ["router"], 30, terminate=True)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    runner = {"cell": asdict(cell), "ids": ids, "started_ns": started_ns, "cpu_series": series,
              "rss_mb": rss, "exit_codes": {n: p.returncode for n, p in procs.items()}, "clk_tck": CLK_TCK,
              "load_avg": _loadavg()}
    (workdir / "runner.json").write_text(json.dumps(runner))
    _compress(workdir, ["gcs", *ids])
    return analyse_run(workdir)


def _compress(workdir: Path, names: list[str]) -> None:
    """The processes' raw records kept gzipped (a drone's are ~0.5 MB of JSON per cell, a third of that zipped)."""
    for n in names:
        path = workdir / f"{n}.json"
        if path.exists():
            with gzip.open(path.with_suffix(".json.gz"), "wb") as f:
                f.write(path.read_bytes())
            path.unlink()


def _stop(procs: dict[str, subprocess.Popen[bytes]], names: list[str], wait: float, terminate: bool = False) -> None:
    for n in names:
        if terminate and procs[n].poll() is None:
            procs[n].terminate()
    for n in names:
        try:
            procs[n].wait(timeout=max(wait, 15.0))
        except subprocess.TimeoutExpired:
            procs[n].kill()


def analyse_run(workdir: Path) -> dict[str, Any]:
    """A cell's result from its directory's raw records (``runner.json`` and the processes' records)."""
    runner = json.loads((workdir / "runner.json").read_text())
    cell = SwarmCell(**runner["cell"])
    ids: list[str] = runner["ids"]
    series = [(int(t), ticks) for t, ticks in runner["cpu_series"]]
    gcs = _load(workdir / "gcs.json") or {}
    window = _flight_window(gcs, ids) if cell.fly else None
    if window is None:   # hover, or no drone reached its pattern: the runner's fixed window
        t0 = int(runner["started_ns"] + cell.warmup * 1e9)
        t1 = int(t0 + cell.duration * 1e9)
    else:
        t0, t1 = window
    cpu = _cpu_over(series, t0, t1, int(runner.get("clk_tck", CLK_TCK)))
    return analyse_cell(cell, workdir, ids, t0, t1, cpu, runner["rss_mb"], runner["exit_codes"],
                        runner.get("load_avg") or [], flight_window=window is not None)


def _flight_window(gcs: dict[str, Any], ids: list[str]) -> tuple[int, int] | None:
    """[first pattern start, last pattern end] of the drones' missions (ns), or None."""
    spans = [m.get("pattern_window") for m in _missions(gcs, ids).values()]
    good = [(a, b) for a, b in (w for w in spans if w) if isinstance(a, (int, float)) and isinstance(b, (int, float))]
    if not good:
        return None
    return int(min(a for a, _ in good) * 1e9), int(max(b for _, b in good) * 1e9)


def _missions(gcs: dict[str, Any], ids: list[str]) -> dict[str, dict[str, Any]]:
    """Each drone's mission record (one drone: the mission itself; several: its ``drones``)."""
    m = gcs.get("mission") or {}
    if "drones" in m:
        return {d: m["drones"].get(d) or {} for d in ids}
    return {ids[0]: m} if len(ids) == 1 and m else {}


def _cpu_over(series: list[tuple[int, dict[str, int | None]]], t0: int, t1: int, clk_tck: int) -> dict[str, float]:
    """% of one core per process between the samples nearest inside [t0, t1] (whole series if too short)."""
    inside = [s for s in series if t0 <= s[0] <= t1]
    if len(inside) < 2:
        inside = series
    if len(inside) < 2:
        return {}
    (a_t, a), (b_t, b) = inside[0], inside[-1]
    elapsed = (b_t - a_t) / 1e9
    out: dict[str, float] = {}
    for n in b:
        # A process that ended inside the window has no last reading: its latest one in the window.
        last = next((s[1][n] for s in reversed(inside) if s[1].get(n) is not None), None)
        first = a.get(n)
        out[n] = float("nan") if first is None or last is None or elapsed <= 0 else \
            100.0 * (int(last) - int(first)) / clk_tck / elapsed
    return out


def reanalyse(out: Path) -> list[dict[str, Any]]:
    """Every cell under ``out`` rebuilt from its raw records; rewrites ``out/results.jsonl``, keeping the
    results recorded before cells kept raw records (no ``runner.json``) as they are."""
    rebuilt = {d.name: analyse_run(d) for d in sorted(out.iterdir()) if (d / "runner.json").exists()}
    results = [r for r in load_results(out / "results.jsonl") if r.get("name") not in rebuilt]
    results += rebuilt.values()
    with (out / "results.jsonl").open("w") as f:
        for res in results:
            f.write(json.dumps(res, default=str, allow_nan=True) + "\n")
    return results


def _load(path: Path) -> dict[str, Any] | None:
    """A process's JSON record, or its gzipped copy (``_compress``)."""
    zipped = path.with_suffix(".json.gz")
    try:
        text = gzip.decompress(zipped.read_bytes()).decode() if zipped.exists() else path.read_text()
        data: dict[str, Any] = json.loads(text)
        return data
    except (OSError, ValueError):
        return None


def analyse_cell(cell: SwarmCell, workdir: Path, ids: list[str], t0: int, t1: int, cpu: dict[str, float],
                 rss: dict[str, float], exit_codes: dict[str, int | None], load_avg: list[float],
                 flight_window: bool = False) -> dict[str, Any]:
    gcs = _load(workdir / "gcs.json") or {}
    out: dict[str, Any] = {"cell": asdict(cell), "name": cell.name, "exit_codes": exit_codes, "drones": {},
                           "cpu_pct": cpu, "rss_mb": rss, "errors": [], "load_avg": load_avg,
                           "window_s": (t1 - t0) / 1e9, "window": "flight" if flight_window else "fixed"}
    window = (t1 - t0) / 1e9
    missions = _missions(gcs, ids)
    if cell.fly:
        m = gcs.get("mission") or {}
        out["mission"] = {"ok": m.get("ok", False), "result": m.get("result", "the GCS wrote no mission record")}
        if not flight_window:
            out["errors"].append("no drone reached its pattern: figures over the runner's fixed window")
    for d in ids:
        comp, g = _load(workdir / f"{d}.json"), gcs.get("drones", {}).get(d)
        if comp is None or g is None:
            out["errors"].append(f"{d}: missing records (see {workdir}/*.log)")
            continue
        gl, dl = g["logs"], comp["logs"]
        rec = StreamRecorder.from_dict
        topics = {
            "setpoint": analyse(rec(dl["received"]["setpoint"]), rec(gl["sent"]["setpoint"]), t0, t1),
            "sensor": analyse(rec(gl["received"]["sensor"]), rec(dl["sent"]["sensor"]), t0, t1),
            "state": analyse(rec(gl["received"]["state"]), rec(dl["sent"]["state"]), t0, t1),
        }
        figures: dict[str, object] = {k: v.as_dict() for k, v in topics.items()}
        image = analyse(rec(gl["received"]["image"]), None, t0, t1)
        sent_frames = analyse(rec(dl["sent"]["image"]), None, t0, t1)
        figures["image"] = {**image.as_dict(), "fps": image.unique / window if window else float("nan"),
                            "sent_fps": sent_frames.unique / window if window else float("nan")}
        # The GCS's figures are judged against what it asked (its downlink), delivered % against the sender.
        downlink = g.get("downlink") or {}
        figures["downlink"] = downlink.get("status", "not asked")
        # What PX4 itself delivers of the asked rate (real PX4 SITL sends ~120 Hz of a 200 Hz ask;
        # see px4_link/README.md): the most the GCS can receive.
        px4_hz = comp.get("sensor_rate_hz")
        figures["sensor_px4_hz"] = float(px4_hz) if isinstance(px4_hz, (int, float)) else float("nan")
        if cell.sensor_rate is not None or cell.camera_rate is not None:
            if downlink.get("status") != "applied":
                out["errors"].append(f"{d}: downlink {downlink.get('status', 'no answer')}: "
                                     f"{downlink.get('detail', '')}")
        if cell.fly:
            figures["flight"] = flight_figures(missions.get(d) or {}, comp, (gcs.get("drones") or {}).get(d) or {})
        # What the GCS said of this drone (silent streams, a second claimant, its own shedding): the per-drone
        # table shows it beside the figures, so a drop is never only a number.
        if "alerts" in g:      # a GCS from before alerts recorded none: the table says "not recorded"
            figures["alerts"] = [str(a) for a in g.get("alerts") or []]
            figures["shed_by_gcs"] = {k: int(v) for k, v in (g.get("shed_by_gcs") or {}).items() if v}
        out["drones"][d] = figures
    out["summary"] = summarize(out, cell)
    return out


def flight_figures(mission: dict[str, Any], companion: dict[str, Any], gcs_drone: dict[str, Any]) -> dict[str, Any]:
    """One drone's flight: the mission's outcome, its path error against its own slot path, its time in
    OFFBOARD over the time asked, its commands, and the companion's failsafes."""
    commands = mission.get("commands") or []
    latencies = sorted(float(c["latency_s"]) for c in commands if c.get("ok"))
    nan = float("nan")
    failsafe = companion.get("failsafe") or {}
    return {
        "ok": bool(mission.get("ok")), "result": str(mission.get("result", "no mission record"))[:300],
        "joined_path": bool(mission.get("joined_path", gcs_drone.get("joined_path", False))),
        "path_error_mean_m": _num(mission.get("mean_path_error_m", gcs_drone.get("mean_path_error_m"))),
        "path_error_max_m": _num(mission.get("max_path_error_m", gcs_drone.get("max_path_error_m"))),
        "offboard_share": _num(mission.get("offboard_share")),
        "offboard_s": _num(mission.get("offboard_s")), "asked_s": _num(mission.get("asked_s")),
        "commands": len(commands), "commands_ok": sum(1 for c in commands if c.get("ok")),
        "command_latency_p50_s": latencies[len(latencies) // 2] if latencies else nan,
        "command_latency_max_s": latencies[-1] if latencies else nan,
        "holds": int(failsafe.get("holds", 0) or 0), "failsafes": int(failsafe.get("triggered", 0) or 0),
    }


def _num(v: object) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else float("nan")


def _loadavg() -> list[float]:
    try:
        return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]
    except (OSError, ValueError):
        return []


def _mean(xs: list[float]) -> float:
    xs = [x for x in xs if x == x]
    return sum(xs) / len(xs) if xs else float("nan")


def _min(xs: list[float]) -> float:
    xs = [x for x in xs if x == x]
    return min(xs) if xs else float("nan")


def _max(xs: list[float]) -> float:
    xs = [x for x in xs if x == x]
    return max(xs) if xs else float("nan")


def summarize(result: dict[str, Any], cell: SwarmCell) -> dict[str, Any]:
    ds = list(result["drones"].values())
    cpu = result["cpu_pct"]
    comp = [v for k, v in cpu.items() if k not in ("gcs", "router")]
    rss = result["rss_mb"]
    return {
        "drones": cell.drones, "mode": cell.mode, "camera": cell.camera, "drones_measured": len(ds),
        "sensor_asked_hz": cell.sensor_rate if cell.sensor_rate is not None else DRONE_SENSOR_HZ,
        "camera_asked_fps": cell.camera_rate if cell.camera_rate is not None else DRONE_CAMERA_FPS,
        "downlink_applied": sum(1 for d in ds if d.get("downlink") == "applied"),
        "load_avg_1m": (result.get("load_avg") or [float("nan")])[0],
        "setpoint_hz_min": _min([d["setpoint"]["rate_hz"] for d in ds]),
        # While the GCS streams to it: the rate over the window also counts the silence after a drone landed
        # (its stream ends there by design) and read 8.3 Hz where the GCS sent 9.97.
        "setpoint_streamed_hz_min": _min([1000.0 / d["setpoint"]["period_avg_ms"] for d in ds
                                          if d["setpoint"].get("period_avg_ms", 0) > 0]),
        "setpoint_gap_p99_ms_max": _max([d["setpoint"].get("gap_p99_ms", float("nan")) for d in ds]),
        "setpoint_delivered_min": _min([d["setpoint"]["delivered_pct"] for d in ds]),
        "sensor_delivered_min": _min([d["sensor"]["delivered_pct"] for d in ds]),
        "sensor_delivered_avg": _mean([d["sensor"]["delivered_pct"] for d in ds]),
        "sensor_hz_avg": _mean([d["sensor"]["rate_hz"] for d in ds]),
        "sensor_px4_hz_avg": _mean([d.get("sensor_px4_hz", float("nan")) for d in ds]),
        "state_delivered_min": _min([d["state"]["delivered_pct"] for d in ds]),
        "image_fps_avg": _mean([d["image"]["fps"] for d in ds]),
        "image_fps_min": _min([d["image"]["fps"] for d in ds]),
        "image_sent_fps_avg": _mean([d["image"]["sent_fps"] for d in ds]),
        "sensor_age_p50_ms": _mean([d["sensor"]["age_p50_ms"] for d in ds]),
        "sensor_age_p99_ms": _mean([d["sensor"]["age_p99_ms"] for d in ds]),
        "setpoint_age_p50_ms": _mean([d["setpoint"]["age_p50_ms"] for d in ds]),
        "setpoint_age_p99_ms": _mean([d["setpoint"]["age_p99_ms"] for d in ds]),
        "cpu_gcs_pct": cpu.get("gcs", float("nan")),
        "cpu_gcs_per_drone_pct": cpu.get("gcs", float("nan")) / cell.drones,
        "cpu_companion_avg_pct": _mean(comp),
        "cpu_router_pct": cpu.get("router", float("nan")),
        "rss_gcs_mb": rss.get("gcs", float("nan")),
        "rss_companion_avg_mb": _mean([v for k, v in rss.items() if k not in ("gcs", "router")]),
        "rss_router_mb": rss.get("router", float("nan")),
        "cpu_total_pct": sum(v for v in cpu.values() if v == v),
        "cores": CORES,
        **(flight_summary([d["flight"] for d in ds if "flight" in d], cell.drones) if cell.fly else {}),
        "fly": cell.fly, "run": cell.run, "window_s": result.get("window_s", float("nan")),
    }


def flight_summary(flights: list[dict[str, Any]], drones: int) -> dict[str, Any]:
    """The cell's flight figures: drones that flew, the worst drone's path error, OFFBOARD share, commands."""
    nan = float("nan")
    commands = sum(f["commands"] for f in flights)
    return {
        "flew_ok": sum(1 for f in flights if f["ok"]), "joined_path": sum(1 for f in flights if f["joined_path"]),
        "path_error_mean_m": _mean([f["path_error_mean_m"] for f in flights]),
        "path_error_mean_max_m": max((f["path_error_mean_m"] for f in flights if f["path_error_mean_m"] == f[
            "path_error_mean_m"]), default=nan),
        "path_error_max_m": max((f["path_error_max_m"] for f in flights if f["path_error_max_m"] == f[
            "path_error_max_m"]), default=nan),
        # A drone with no mission record counts as 0 % in OFFBOARD: it never flew.
        "offboard_share_min": min([f["offboard_share"] if f["offboard_share"] == f["offboard_share"] else 0.0
                                   for f in flights] + ([0.0] if len(flights) < drones else []), default=nan),
        "commands": commands,
        "commands_ok_pct": 100.0 * sum(f["commands_ok"] for f in flights) / commands if commands else nan,
        "command_latency_max_s": max((f["command_latency_max_s"] for f in flights
                                      if f["command_latency_max_s"] == f["command_latency_max_s"]), default=nan),
        "command_latency_p50_s": _mean([f["command_latency_p50_s"] for f in flights]),
        "holds": sum(f["holds"] for f in flights), "failsafes": sum(f["failsafes"] for f in flights),
    }


def run_sweep(out: Path, cells: list[SwarmCell], say: Any = print) -> list[dict[str, Any]]:
    out.mkdir(parents=True, exist_ok=True)
    results = []
    with (out / "results.jsonl").open("a") as f:
        for cell in cells:
            say(f"swarm: {cell.name}: " + (f"mission: {cell.duration:g} s of {cell.pattern} in a {cell.formation} ..."
                                           if cell.fly else f"{cell.warmup:g} s warm-up + {cell.duration:g} s "
                                                            "measured ..."))
            res = run_cell(cell, out / cell.name)
            s = res["summary"]
            flown = (f"flew {s['flew_ok']}/{cell.drones}, path error mean {s['path_error_mean_m']:.2f} m max "
                     f"{s['path_error_max_m']:.2f} m, OFFBOARD >= {100 * s['offboard_share_min']:.0f} %, commands "
                     f"{s['commands_ok_pct']:.0f} % ok; ") if cell.fly else ""
            say(f"swarm: {cell.name}: {flown}setpoints >= {s['setpoint_streamed_hz_min']:.1f} Hz while streamed, "
                f"p99 gap {s['setpoint_gap_p99_ms_max']:.0f} ms ({s['setpoint_delivered_min']:.1f} %), "
                f"sensor >= {s['sensor_delivered_min']:.1f} %, images {s['image_fps_avg']:.1f} fps, "
                f"GCS {s['cpu_gcs_pct']:.0f} % CPU" + (f"; errors: {res['errors']}" if res["errors"] else ""))
            f.write(json.dumps(res, default=str, allow_nan=True) + "\n")
            f.flush()
            results.append(res)
    return results


def load_results(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


# -- launch files ---------------------------------------------------------------------------
def swarm_launch(drones: int, camera: str = "test", prefix: str = "uav") -> str:
    """A launch file (zenoh-robot launch) for router + N companions with simulators + GCS."""
    if not 1 <= drones <= 250:
        raise ValueError(f"drones must be 1..250 (a MAVLink sysid each), got {drones}")
    ids = [f"{prefix}{i + 1}" for i in range(drones)]
    lines = [
        f"# Generated by `zenoh-robot swarm launch --drones {drones}`: a router, {drones} companions (each with",
        "# its own built-in simulator, sysid and UDP port) and one GCS, all clients of the router.",
        "# zenoh-robot launch THIS_FILE duration:=60 pattern:=circle",
        "# Loopback: the router listens where configs/zenoh/client.json5 connects (127.0.0.1:7447; edit both).",
        "args:",
        "  duration: {default: \"120\", description: seconds before everything stops}",
        "  pattern: {default: hover}",
        "  formation: {default: line}",
        f"  camera: {{default: {camera}, description: \"test, a device, or none\"}}",
        "  profile: {default: resilient}",
        f"  sensor_rate: {{default: \"{SWARM_SENSOR_HZ:g}\", description: \"Hz of SensorCombined the GCS asks of "
        f"each drone ({DRONE_SENSOR_HZ:g}: the drone's own)\"}}",
        f"  camera_rate: {{default: \"{SWARM_CAMERA_FPS:g}\", description: \"camera fps the GCS asks of each drone "
        f"({DRONE_CAMERA_FPS:g}: the drone's own)\"}}",
        "processes:",
        "  - name: router",
        "    exec: zenoh-robot router --no-scouting --status 10",
        "    args: [\"--listen\", \"tcp/127.0.0.1:7447\", \"--duration\", \"$(arg duration)\"]",
    ]
    for i, d in enumerate(ids):
        lines += [
            f"  - name: {d}",
            "    module: companion",
            f"    args: [\"--id\", \"{d}\", \"--px4\", \"sim\", \"--sysid\", \"{i + 1}\",",
            "           \"--camera\", \"$(arg camera)\",",
            "           \"--profile\", \"$(arg profile)\", \"--zenoh\", \"$(dirname)/../zenoh/client.json5\"]",
            "    depends_on: [router]",
            "    delay: 1.0",
        ]
    lines += [
        "  - name: gcs",
        "    module: gcs",
        f"    args: [\"--drones\", \"{','.join(ids)}\", \"--no-dashboard\", \"--pattern\", \"$(arg pattern)\",",
        "           \"--formation\", \"$(arg formation)\", \"--profile\", \"$(arg profile)\",",
        "           \"--zenoh\", \"$(dirname)/../zenoh/client.json5\", \"--duration\", \"$(arg duration)\",",
        "           \"--sensor-rate\", \"$(arg sensor_rate)\", \"--camera-rate\", \"$(arg camera_rate)\"]",
        f"    depends_on: [router, {', '.join(ids)}]",
        "    delay: 2.0",
    ]
    return "\n".join(lines) + "\n"
