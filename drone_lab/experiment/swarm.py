"""Swarm scaling sweep: one GCS and N drones (each with its own simulator), peer mode or via a router.

Every cell runs real processes on loopback only: ``zenoh-robot router`` (router mode), the
GCS (``python -m gcs``, no dashboard, streaming setpoints at 10 Hz to every drone) and N
companions (``python -m companion --px4 sim``: a simulator per drone, its own sysid and
UDP port). Peer mode: the GCS listens on loopback TCP+UDP and every companion connects to
it (no multicast scouting, so a sweep never meets another system on the machine). Router
mode: everyone is a client of the router.

Figures over the measured window, from the processes' own raw records (exact sequence
numbers joined sender-to-receiver, as the lossy-link experiment does): per drone the
setpoint rate and delivered %, sensor and state delivered %, image fps and age; per
process the CPU share of one core (from /proc) and resident memory.

This module only starts processes; it never imports the drone system (tools layer).
"""
from __future__ import annotations

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

    @property
    def name(self) -> str:
        rates = "" if self.sensor_rate is None and self.camera_rate is None else \
            f"_s{self.sensor_rate or 0:g}c{self.camera_rate or 0:g}"
        return f"n{self.drones}_{self.mode}_{'cam' if self.camera else 'nocam'}{rates}"


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
    """Run one cell; its processes' logs and records stay in ``workdir``."""
    workdir.mkdir(parents=True, exist_ok=True)
    prefix = f"sw{secrets.token_hex(2)}"
    ids = [f"{prefix}_{i + 1}" for i in range(cell.drones)]
    port = _free_port()
    endpoints = [f"tcp/127.0.0.1:{port}", f"udp/127.0.0.1:{port}"]
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
    total = cell.warmup + cell.duration + 2.0 + stagger
    cmds: dict[str, list[str]] = {}
    if cell.mode == "router":
        cmds["router"] = ZENOH_ROBOT + ["router", "--no-scouting", "--status", "0", "--duration", str(total + 8),
                                        *sum((["--listen", e] for e in endpoints), [])]
    else:   # the GCS listens: start it first
        cmds["gcs"] = []
    for i, d in enumerate(ids):
        cmds[d] = [sys.executable, "-m", "companion", "--id", d, "--px4", "sim", "--sysid", str(i + 1),
                   "--zenoh", str(workdir / "drone.json5"), "--profile", cell.profile, "--duration", str(total),
                   "--camera", "test" if cell.camera else "none", "--record", str(workdir / f"{d}.json")]
    cmds["gcs"] = [sys.executable, "-m", "gcs", "--drones", ",".join(ids), "--no-dashboard", "--pattern", "hover",
                   "--zenoh", str(workdir / "gcs.json5"), "--profile", cell.profile, "--duration", str(total),
                   "--record", str(workdir / "gcs.json"), "--gcs-id", f"{prefix}_gcs"]
    if cell.sensor_rate is not None:
        cmds["gcs"] += ["--sensor-rate", f"{cell.sensor_rate:g}"]
    if cell.camera_rate is not None:
        cmds["gcs"] += ["--camera-rate", f"{cell.camera_rate:g}"]
    order = (["router"] if cell.mode == "router" else ["gcs"]) + ids + (["gcs"] if cell.mode == "router" else [])
    procs: dict[str, subprocess.Popen[bytes]] = {}
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    try:
        for name in order:
            log = open(workdir / f"{name}.log", "w")
            procs[name] = subprocess.Popen(cmds[name], stdout=log, stderr=subprocess.STDOUT, env=env)
            time.sleep(LAUNCH_GAP_S if name != "router" else ROUTER_GAP_S)
        time.sleep(cell.warmup)
        ticks0 = {n: cpu_ticks(p.pid) for n, p in procs.items()}
        t0, m0 = time.time_ns(), time.monotonic()
        time.sleep(cell.duration)
        ticks1 = {n: cpu_ticks(p.pid) for n, p in procs.items()}
        rss = {n: rss_mb(p.pid) for n, p in procs.items()}
        t1, elapsed = time.time_ns(), time.monotonic() - m0
        for name in ["gcs", *ids, *(["router"] if cell.mode == "router" else [])]:
            try:
                procs[name].wait(timeout=total + 30)
            except subprocess.TimeoutExpired:
                procs[name].kill()
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    cpu = {n: _cpu_pct(ticks0.get(n), ticks1.get(n), elapsed) for n in procs}
    return analyse_cell(cell, workdir, ids, t0, t1, cpu, rss, {n: p.returncode for n, p in procs.items()})


def _cpu_pct(ticks0: int | None, ticks1: int | None, elapsed: float) -> float:
    """% of one core over ``elapsed`` s; nan when a reading failed (the process had gone)."""
    if ticks0 is None or ticks1 is None:
        return float("nan")
    return 100.0 * (ticks1 - ticks0) / CLK_TCK / elapsed


def _load(path: Path) -> dict[str, Any] | None:
    try:
        data: dict[str, Any] = json.loads(path.read_text())
        return data
    except (OSError, ValueError):
        return None


def analyse_cell(cell: SwarmCell, workdir: Path, ids: list[str], t0: int, t1: int, cpu: dict[str, float],
                 rss: dict[str, float], exit_codes: dict[str, int | None]) -> dict[str, Any]:
    gcs = _load(workdir / "gcs.json") or {}
    out: dict[str, Any] = {"cell": asdict(cell), "name": cell.name, "exit_codes": exit_codes, "drones": {},
                           "cpu_pct": cpu, "rss_mb": rss, "errors": [], "load_avg": _loadavg()}
    window = (t1 - t0) / 1e9
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
        out["drones"][d] = figures
    out["summary"] = summarize(out, cell)
    return out


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
    }


def run_sweep(out: Path, cells: list[SwarmCell], say: Any = print) -> list[dict[str, Any]]:
    out.mkdir(parents=True, exist_ok=True)
    results = []
    with (out / "results.jsonl").open("a") as f:
        for cell in cells:
            say(f"swarm: {cell.name}: {cell.warmup:g} s warm-up + {cell.duration:g} s measured ...")
            res = run_cell(cell, out / cell.name)
            s = res["summary"]
            say(f"swarm: {cell.name}: setpoints >= {s['setpoint_hz_min']:.1f} Hz "
                f"({s['setpoint_delivered_min']:.1f} %), "
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
        "    args: [\"--listen\", \"tcp/127.0.0.1:7447\", \"--listen\", \"udp/127.0.0.1:7447\",",
        "           \"--duration\", \"$(arg duration)\"]",
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
