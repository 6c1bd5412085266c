"""One experiment cell: a profile at a loss rate, GCS and drone in their own namespaces, flying.

The GCS (``python -m gcs --mission``) runs in one namespace; the companion with its built-in
PX4 simulator (``python -m companion --px4 sim``) in the other. They talk over the
veth as a real deployment would, with the transport of the profile. The GCS flies a mission:
OFFBOARD, arm, climb, the pattern, land. The loss comes on ``warmup`` s into the pattern
(``start="after"``) or is there from start-up; the window is the ``duration`` s after that, and
the loss stays on through the landing. Both ends keep a raw record of what they sent and
received; the cell joins them over the window, so delivered % is exact (unique sequence numbers
received / sent). The companion's vehicle record (``--vehicle-record``) and the mission's steps
give the flight's figures (flight.py).
"""
from __future__ import annotations

import dataclasses
import json
import math
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

from drone_contract.streams import stream_profile
from zenoh_robot.session_config import RESILIENT_GROUP, SessionConfig
from zenoh_robot.tools.stream_metrics import StreamRecorder, analyse

from .flight import OFFBOARD_GAP_MS, flight_figures
from .netns import LOSS_MODELS as LOSS_MODEL_NAMES
from .netns import BurstModel, LossyLink

DRONE_ID = "uav1"
PORT = 7447
MCAST = RESILIENT_GROUP
STARTUP_TIMEOUT_S = 60.0   # launch -> both apps up; streams began 6-11 s after launch on a loaded 2-core machine
# Both apps up -> the pattern flown: the mission's own bounds (connected 30 s, armable 30 s, climb 30 s).
AIRBORNE_TIMEOUT_S = 100.0
LANDING_TIMEOUT_S = 75.0    # the pattern's end -> the GCS's exit (land and disarm: the mission waits 40 s)
PATTERN_SIZE_M = 10.0
TAIL_S = 3.0                # the pattern goes on this long after the window: the land is never inside it


@dataclass(frozen=True)
class CellSpec:
    profile: str
    loss: float
    start: str = "after"        # "after": loss once sessions are up (the thesis); "startup": from the start
    duration: float = 20.0
    warmup: float = 5.0
    transport: str = "default"  # the profile's own; "unicast": resilient over a UDP/TCP peer-to-peer session;
    # "router": a Zenoh router in the GCS namespace, the GCS its client over loopback, the drone across the veth
    # (the thesis's variants too: plain clients over one TCP link each, as rmw_zenoh deploys them)
    startup_timeout: float = STARTUP_TIMEOUT_S   # launch -> both apps up (a client's up = its session formed)
    loss_model: str = "uniform"   # "bursty": the netns two-state channel at the same mean (netns.BurstyChannel)
    burst_mean_s: float = 0.3     # the bursty channel's mean fade (clamped 0.1-2 s)
    pattern: str = "square"       # what the GCS's mission flies (gcs --pattern)
    run: int = 0                  # the repeat of this cell (the report gives median and range over runs)

    @property
    def pattern_s(self) -> float:
        """How long the mission flies its pattern: warm-up, window and a tail, all inside it."""
        return self.warmup + self.duration + TAIL_S

    @property
    def label(self) -> str:
        label = self.profile if self.transport == "default" else f"{self.profile}@{self.transport}"
        return label if self.loss_model == "uniform" else f"{label}~{self.loss_model}"


TRANSPORTS = ("default", "unicast", "router", "router-udp", "router-shim")
LOSS_MODELS = LOSS_MODEL_NAMES


class _Tuning(TypedDict, total=False):
    """``SessionConfig`` keywords a cell's config shares between its two sides (the thesis's variants)."""
    multicast_scouting: bool
    shared_memory: bool
    accept_timeout_s: float


ROUTER_LOCAL = f"tcp/127.0.0.1:{PORT}"     # the GCS reaches its ground router over loopback


def router_cmd(link: LossyLink) -> list[str]:
    """The ground router (``zenoh-robot router --lossy``) in the GCS namespace."""
    gcs = link.addr("gcs")
    return [sys.executable, "-m", "zenoh_robot.tools.cli.main", "router", "--lossy", "--no-scouting",
            "--status", "0", "--listen", f"udp/{gcs}:{PORT}", "--listen", f"tcp/{gcs}:{PORT}",
            "--listen", ROUTER_LOCAL]


def transport_for(profile: str, link: LossyLink, side: str, transport: str = "default") -> dict[str, Any]:
    """The Zenoh config of one side, as JSON (valid JSON5) for ``--zenoh``.

    The resilient cells run the product's session (``stream_profile(...).session_config()``: fast open,
    UDP first, lossy TX settings), given the endpoints a user would pass (``--listen``/``--connect``/
    ``--mode``): what is measured is what a user gets. Only the topology is the cell's own."""
    if profile == "resilient" and transport in ("router", "router-udp", "router-shim", "unicast"):
        base = dataclasses.replace(stream_profile(profile).session_config(), multicast_scouting=False,
                                   shared_memory=False)
        gcs_endpoints = [f"udp/{link.addr('gcs')}:{PORT}", f"tcp/{link.addr('gcs')}:{PORT}"]
        if transport == "unicast":
            if side == "gcs":
                return dataclasses.replace(base, listen=gcs_endpoints).to_json5()
            return dataclasses.replace(base, listen=[], connect=gcs_endpoints).to_json5()
        # Both clients of the ground router (a lossy client's open blocks until its session is up and
        # retries forever): the companion holds (no setpoints, PX4 never armed) meanwhile.
        extra: dict[str, Any] = {}
        if side == "gcs":
            connect = [ROUTER_LOCAL]
        elif transport == "router":
            # A client holds one link unless told to open all of a group (Zenoh >= 1.10): the TCP link
            # carries the reliable control plane (declarations, queries), the UDP link the best-effort
            # streams, which outlive the TCP link at 90 % loss (docs/lossy-link-notes.md).
            connect = gcs_endpoints
            extra["connect/endpoints"] = [{"strategy": "allOf", "locators": connect}]
        elif transport == "router-shim":   # one UDP link through the repeating shim (docs/results/linkshim.md)
            connect = [f"udp/127.0.0.1:{SHIM_LOCAL}"]
        else:   # "router-udp": one UDP link (forms fastest; the control plane then rides it unacknowledged)
            connect = gcs_endpoints[:1]
        return dataclasses.replace(base, mode="client", listen=[], connect=connect, extra=extra).to_json5()
    if profile == "resilient":
        return stream_profile(profile).session_config(link.dev(side)).to_json5()
    # The thesis's variants as a plain deployment would run them: TCP for reliable, UDP for best
    # effort, Zenoh's default lease, batch size and accept timeout; no shared memory (loss must
    # touch every byte).
    endpoints = [f"tcp/{link.addr('gcs')}:{PORT}", f"udp/{link.addr('gcs')}:{PORT}"]
    plain: _Tuning = {"multicast_scouting": False, "shared_memory": False, "accept_timeout_s": 10.0}
    if transport == "router":
        # As rmw_zenoh deploys them: both apps clients of the ground router over one TCP link.
        connect = [ROUTER_LOCAL] if side == "gcs" else endpoints[:1]
        return SessionConfig(mode="client", listen=[], connect=connect, **plain).to_json5()
    if transport != "default":
        raise ValueError(f"transport {transport!r} is flown with the resilient profile only")
    if side == "gcs":
        cfg = SessionConfig(listen=endpoints, **plain)
    else:
        cfg = SessionConfig(listen=[], connect=endpoints, **plain)
    return cfg.to_json5()


def _wait_log(path: Path, mark: str, procs: dict[str, subprocess.Popen[bytes]], timeout: float) -> float | None:
    """Monotonic time ``mark`` appeared in ``path`` (None: not within ``timeout``, or an app exited)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            if mark in path.read_text(errors="replace"):
                return time.monotonic()
        except OSError:
            pass
        if any(p.poll() is not None for p in procs.values()):
            return None
        time.sleep(0.05)
    return None


def _wait_started(workdir: Path, procs: dict[str, subprocess.Popen[bytes]], timeout: float) -> float | None:
    """Seconds until both apps have logged their start (the GCS has its drone, the companion its PX4);
    None on timeout or exit. The streams follow within ~1-2 s: the warm-up covers that."""
    marks = {"gcs.log": f"drone {DRONE_ID} joined", "drone.log": f"companion {DRONE_ID}: PX4 at"}
    t_start = time.monotonic()
    while time.monotonic() - t_start < timeout:
        try:
            if all(mark in (workdir / name).read_text(errors="replace") for name, mark in marks.items()):
                return time.monotonic() - t_start
        except OSError:
            pass
        if any(p.poll() is not None for p in procs.values()):
            return None
        time.sleep(0.1)
    return None


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stop(procs: dict[str, subprocess.Popen[bytes]], timeout: float) -> None:
    """Ctrl-C both apps (each writes its record on the way out); kill what is left after ``timeout``."""
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGINT)    # `ip netns exec` execs the app: the pid is the app's
    end = time.monotonic() + timeout
    for p in procs.values():
        try:
            p.wait(timeout=max(0.1, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def run_cell(spec: CellSpec, workdir: Path) -> dict[str, Any]:
    """The window [t0, t1] is timed from the apps, not from the launch: it opens ``warmup`` s after
    both have started, and the apps run until the parent stops them after t1. On a loaded
    machine start-up took 6-11 s and the parent's own steps (nft, ip) seconds more; a window timed
    from the launch then covered seconds before the apps streamed or after they had exited, and the
    analysis read that as every stream going silent at once (docs/zenoh-multicast-stall.md)."""
    workdir.mkdir(parents=True, exist_ok=True)
    with LossyLink(loss_pct=spec.loss if spec.start == "startup" else 0.0, loss_model=spec.loss_model,
                   burst=BurstModel(bad_mean_s=spec.burst_mean_s)) as link:
        procs = {}
        for side in ("gcs", "drone"):
            (workdir / f"{side}.json5").write_text(
                json.dumps(transport_for(spec.profile, link, side, spec.transport), indent=1))
        # A backstop only (the parent stops the apps): they must outlive any start-up and the window.
        if spec.transport.startswith("router"):
            procs["router"] = _start_router(link, workdir)
        if spec.transport == "router-shim":
            procs.update(_start_shims(link, workdir))
        backstop = spec.startup_timeout + AIRBORNE_TIMEOUT_S + spec.pattern_s + LANDING_TIMEOUT_S + 30
        drone_cmd = [sys.executable, "-m", "companion", "--id", DRONE_ID, "--px4", "sim", "--profile", spec.profile,
                     "--zenoh", str(workdir / "drone.json5"), "--record", str(workdir / "drone.json"),
                     "--vehicle-record", str(workdir / "vehicle.jsonl"), "--duration", str(backstop)]
        # The mission flies the pattern for pattern_s, then lands; the GCS exits once the drone is down.
        gcs_cmd = [sys.executable, "-m", "gcs", "--drones", DRONE_ID, "--no-dashboard", "--mission", "--insecure-ok",
                   "--pattern", spec.pattern, "--size", str(PATTERN_SIZE_M), "--profile", spec.profile,
                   "--duration", str(spec.pattern_s),
                   "--zenoh", str(workdir / "gcs.json5"), "--record", str(workdir / "gcs.json")]
        launch_ns = time.time_ns()
        for side, cmd in (("drone", drone_cmd), ("gcs", gcs_cmd)):
            log = open(workdir / f"{side}.log", "w")
            # Ctrl-C must reach the app even when this runs in the background (nohup, `&`: SIGINT ignored).
            procs[side] = subprocess.Popen(link.exec_in(side) + cmd, stdout=log, stderr=subprocess.STDOUT,
                                           preexec_fn=_default_sigint)
        try:
            apps = {k: procs[k] for k in ("gcs", "drone")}
            startup_s = _wait_started(workdir, apps, spec.startup_timeout)
            # Still running yet not started: the companion's open is waiting for its session (client).
            waiting = startup_s is None and all(p.poll() is None for p in procs.values())
            airborne = None if startup_s is None else _wait_log(
                workdir / "gcs.log", f"mission: {DRONE_ID}: flying the", apps, AIRBORNE_TIMEOUT_S)
            pattern_at = time.time_ns()
            # In the air and in OFFBOARD, the pattern flown clean for the warm-up; no flight: say so at once.
            time.sleep(spec.warmup if airborne is not None else 0)
            if spec.start == "after":
                link.set_loss(spec.loss)
            tx0 = {side: link.tx_bytes(side) for side in link.sides}
            t0 = time.time_ns()
            probe_at = time.monotonic() + spec.duration / 2
            probe: dict[str, Any] = {}
            prober = None
            if airborne is not None:
                time.sleep(max(0.0, probe_at - time.monotonic()))
                # A hold from a second GCS, across the loss, mid-window: answered (refused: that GCS holds no
                # control) by the real companion, without disturbing the mission. On a thread of its own: the
                # second GCS's start-up (seconds) must not stretch the window past the pattern.
                if _probe_reaches(spec):
                    prober = threading.Thread(target=lambda: probe.update(result=_command_probe(link, workdir)),
                                              name="cell-probe", daemon=True)
                    prober.start()
                time.sleep(max(0.0, t0 / 1e9 + spec.duration - time.time()))
            t1 = time.time_ns()
            tx1 = {side: link.tx_bytes(side) for side in link.sides}
            apps_ran = all(p.poll() is None for p in apps.values())
            # The loss stays on through the landing: the land command crosses it too.
            if airborne is not None:
                try:
                    procs["gcs"].wait(timeout=TAIL_S + LANDING_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    pass     # stopped below; its mission record says how far the landing got
            landed_s = round((time.time_ns() - t1) / 1e9, 2)
            if prober is not None:
                prober.join(timeout=60.0)   # two tries of `gcs cmd --timeout 12` with their start-ups
            command = probe.get("result")
            link.set_loss(0)
            time.sleep(1.0)       # the last samples land
            # A companion still in its session's open (Rust) cannot take Ctrl-C: kill it after a moment.
            _stop(apps, timeout=5.0 if waiting else 30.0)
            if "router" in procs:      # after the apps: they say goodbye through it
                _stop({"router": procs["router"]}, timeout=10.0)
            shims = {k: p for k, p in procs.items() if k.startswith("shim-")}
            if shims:
                _stop(shims, timeout=5.0)
        finally:
            for p in procs.values():
                if p.poll() is None:
                    p.kill()
                    p.wait()
    timed_t1 = t1
    t1 = min(t1, _pattern_end_ns(workdir, spec.pattern_s) or t1)
    channel = link.timeline_summary(t0, t1)
    result = analyse_cell(spec, workdir, t0, t1, {k: p.returncode for k, p in procs.items()})
    result["run"] = spec.run
    result["pattern"] = spec.pattern
    result["flight"] = flight_figures(workdir, (t0, t1), spec.pattern, PATTERN_SIZE_M, spec.pattern_s, DRONE_ID)
    result["flight"]["airborne"] = airborne is not None
    result["flight"]["pattern_to_loss_s"] = round((t0 - pattern_at) / 1e9, 2)
    result["flight"]["window_to_gcs_exit_s"] = landed_s
    if command is not None:
        result["flight"]["commands"]["hold"] = {"ok": bool(command["answered"]), "s": command["s"],
                                                "attempts": command.get("attempts", 1),
                                                "detail": command["reply"], "probe": True}
    fl = result["flight"]
    # Kept = flown through the whole window in OFFBOARD, armed, no failsafe (what PX4 did, not inferred).
    result["offboard_kept"] = bool(fl["armed_in_window"] and fl["offboard_share_window"] == 1.0
                                   and not fl["failsafes"])
    if not fl["mission_ok"] and result.get("invalid"):
        # The mission failed (a failsafe, the link): the GCS stopped streaming early. A result, not a rerun.
        result["mission_failed"] = f"{fl['mission_result']} ({result.pop('invalid')})"
    elif airborne is None and startup_s is not None and not waiting:
        result["mission_failed"] = f"never flew the pattern: {fl['mission_result']}"
        result.pop("invalid", None)
    # Everything each side put on the wire in the window (all streams, copies and joins included).
    result["bandwidth_kBps"] = {side: (tx1[side] - tx0[side]) / 1000 / max(1e-9, (timed_t1 - t0) / 1e9)
                                for side in tx0}     # the bytes were read at the timed end
    result["startup_s"] = startup_s        # launch -> both apps started (None: not within the timeout)
    result.update(formation(workdir, launch_ns))
    if command is not None:
        result["command"] = command     # the probe's raw answer (flight.commands.hold is its figure)
    if result.get("invalid") and apps_ran and startup_s is not None:
        # Both apps ran through the window, yet a sender had nothing to send: the GCS streams
        # setpoints only to a drone it hears, the drone senses only while its session lives. That is
        # the link failing the stack (the thesis's "nothing"), a result, not a window to rerun.
        result["link_failed"] = (f"{result.pop('invalid').split(' not sent')[0]} not sent in the window although "
                                 "both apps ran: the GCS streams only to a drone it hears (no session)")
        for name in ("setpoint", "sensor"):
            topic = result["topics"].get(name, {})
            if not topic.get("unique"):
                topic["delivered_pct"] = 0.0
    if spec.transport == "router-shim":
        result["shim"] = {side: _last_json(workdir / f"shim-{side}.log") for side in link.sides}
    if waiting:
        # Not a window to skip: the link did not let the session form (a client's open blocks until it
        # does; the companion meanwhile sends nothing and PX4 is never armed).
        result["error"] = f"no session within {spec.startup_timeout:g} s of launch (see {workdir}/*.log)"
        result["no_session"] = True
        result["session_formed_s"] = None   # what arrived came with the stop (Ctrl-C ends the open's retries)
        result.pop("invalid", None)
    result["window_ns"] = [t0, t1]
    if timed_t1 > t1:
        result["window_cut_s"] = round((timed_t1 - t1) / 1e9, 3)
    # What the link applied in the window (the bursty channel's fades), and its raw timeline.
    result["loss_model"] = spec.loss_model
    result["channel"] = channel
    (workdir / "loss_timeline.json").write_text(json.dumps(link.timeline))
    return result


def _start_router(link: LossyLink, workdir: Path) -> subprocess.Popen[bytes]:
    """Start the ground router and wait for its first line (it listens from then on)."""
    log_path = workdir / "router.log"
    log = open(log_path, "w")
    proc = subprocess.Popen(link.exec_in("gcs") + router_cmd(link), stdout=log, stderr=subprocess.STDOUT,
                            preexec_fn=_default_sigint)
    end = time.monotonic() + STARTUP_TIMEOUT_S
    while time.monotonic() < end and proc.poll() is None:
        if "listening on" in log_path.read_text(errors="replace"):
            return proc
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    raise RuntimeError(f"router did not start (see {log_path})")


SHIM_LOCAL = 7448      # the drone end of the shim, on the drone's loopback (the companion connects to it)
SHIM_WIRE = 7449       # the ground end, on the veth


def _start_shims(link: LossyLink, workdir: Path) -> dict[str, subprocess.Popen[bytes]]:
    """``zenoh-robot linkshim`` at both ends (the ground end forwards to the router's UDP endpoint), each
    waited for until it listens; each prints its counters as JSON when stopped."""
    gcs = link.addr("gcs")
    cli = [sys.executable, "-m", "zenoh_robot.tools.cli.linkshim"]
    cmds = {"gcs": cli + ["ground", "--listen", f"{gcs}:{SHIM_WIRE}", "--target", f"{gcs}:{PORT}"],
            "drone": cli + ["drone", "--listen", f"127.0.0.1:{SHIM_LOCAL}", "--peer", f"{gcs}:{SHIM_WIRE}"]}
    procs = {}
    for side, cmd in cmds.items():
        path = workdir / f"shim-{side}.log"
        procs[f"shim-{side}"] = p = subprocess.Popen(link.exec_in(side) + cmd, stdout=open(path, "w"),
                                                     stderr=subprocess.STDOUT, preexec_fn=_default_sigint)
        end = time.monotonic() + 30
        while "listening" not in path.read_text(errors="replace"):
            if p.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"linkshim {side} did not start (see {path})")
            time.sleep(0.05)
    return procs


def _last_json(path: Path) -> dict[str, Any] | None:
    try:
        lines = [x for x in path.read_text(errors="replace").splitlines() if x.startswith("{")]
        return json.loads(lines[-1]) if lines else None
    except (OSError, ValueError):
        return None


def _probe_reaches(spec: CellSpec) -> bool:
    """A second GCS process can reach the companion: through the router, or on the multicast group.
    The plain and unicast cells listen on the GCS's fixed port, which a second process cannot share."""
    return spec.transport.startswith("router") or (spec.profile == "resilient" and spec.transport == "default")


def _command_probe(link: LossyLink, workdir: Path, timeout: float = 12.0, tries: int = 2) -> dict[str, Any]:
    """A service call GCS -> companion across the loss: ``gcs cmd uav1 hold`` from a second GCS. Any
    answer counts, a refusal too (this GCS holds no control): the query crossed both ways and the real
    companion answered it. A process that got no answer is followed by one more, as an operator would
    (a new client's declarations ride the router's TCP link, which stalls under loss: docs/lossy-link.md);
    ``attempts`` says how many it took. 12 s each: a new TCP connection's SYN is resent after 1, 2 and 4 s,
    so at 30 % loss 6 s left both tries unanswered in about one CI rehearsal of six."""
    out: dict[str, Any] = {}
    for attempt in range(1, tries + 1):
        out = _command_once(link, workdir, timeout)
        out["attempts"] = attempt
        if out["answered"]:
            break
    return out


def _command_once(link: LossyLink, workdir: Path, timeout: float) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "zenoh_robot.tools.cli.main", "gcs", "cmd", DRONE_ID, "hold", "--timeout",
           str(timeout), "--zenoh", str(workdir / "gcs.json5"), "--gcs-id", "cell-probe"]
    t = time.monotonic()
    try:
        res = subprocess.run(link.exec_in("gcs") + cmd, capture_output=True, text=True, timeout=timeout + 30)
    except subprocess.TimeoutExpired:
        return {"rc": None, "reply": "timed out", "s": round(time.monotonic() - t, 2), "answered": False}
    lines = [x for x in (res.stdout + res.stderr).splitlines() if x.strip()]
    reply = next((x for x in reversed(lines) if x.startswith(f"{DRONE_ID} hold")), lines[-1] if lines else "")
    answered = "(mode " in reply      # `gcs cmd` prints the drone's mode only with its CommandResult
    return {"rc": res.returncode, "reply": reply[-300:], "tail": [x[-300:] for x in lines[-6:]],
            "s": round(time.monotonic() - t, 2), "answered": answered}


def formation(workdir: Path, launch_ns: int) -> dict[str, Any]:
    """When the session carried its first sample each way, in s after the apps' launch (None: never).

    Includes the apps' own start-up (~1-3 s here, the 0 % cells show it); a client's ``open`` blocks
    until its session is up, so for the router transport this is the handshake across the loss."""
    gcs, drone = _load(workdir / "gcs.json"), _load(workdir / "drone.json")

    def first(rec: dict[str, Any] | None) -> float | None:
        arrivals = (rec or {}).get("arrival_ns") or []
        return round((min(arrivals) - launch_ns) / 1e9, 3) if arrivals else None
    to_drone = first(((drone or {}).get("logs") or {}).get("received", {}).get("setpoint"))
    to_gcs = first((((gcs or {}).get("drones") or {}).get(DRONE_ID, {}).get("logs") or {})
                   .get("received", {}).get("sensor"))
    both = None if to_drone is None or to_gcs is None else max(to_drone, to_gcs)
    return {"session_formed_s": both, "first_setpoint_s": to_drone, "first_sensor_s": to_gcs}


def _load(path: Path) -> dict[str, Any] | None:
    try:
        data: dict[str, Any] = json.loads(path.read_text())
        return data
    except (OSError, ValueError):
        return None


def _pattern_end_ns(workdir: Path, pattern_s: float) -> int | None:
    """When the GCS's pattern was to end (its start in the GCS's record, ``pattern_window``, plus its duration),
    as wall ns; None if it never started. The window ends there at the latest: switching the loss on costs four
    subprocesses, seconds on a loaded machine (rehearsal 16), so a window timed from it could outrun the
    pattern's tail and take the land in. The planned end, not the one the record shows: a mission that failed
    early must not cut its failure out of the window."""
    gcs = _load(workdir / "gcs.json") or {}
    window = (gcs.get("mission") or {}).get("pattern_window") or []
    start = window[0] if window and isinstance(window[0], float) else None
    return None if start is None or math.isnan(start) else int((start + pattern_s) * 1e9)


def analyse_cell(spec: CellSpec, workdir: Path, t0: int, t1: int, exit_codes: dict[str, int]) -> dict[str, Any]:
    gcs, drone = _load(workdir / "gcs.json"), _load(workdir / "drone.json")
    result: dict[str, Any] = {"profile": spec.label, "transport": spec.transport, "loss": spec.loss,
                              "start": spec.start, "duration": spec.duration, "exit_codes": exit_codes, "topics": {},
                              "config": stream_profile(spec.profile).summary()}
    if gcs is None or drone is None or DRONE_ID not in gcs.get("drones", {}):
        result["error"] = f"missing records (see {workdir}/*.log)"
        return result
    g = gcs["drones"][DRONE_ID]["logs"]
    d = drone["logs"]

    def rec(x: dict[str, Any]) -> StreamRecorder:
        return StreamRecorder.from_dict(x)

    pairs = {"setpoint": (d["received"]["setpoint"], g["sent"]["setpoint"]),
             "sensor": (g["received"]["sensor"], d["sent"]["sensor"]),
             "image": (g["received"]["image"], d["sent"]["image"]),
             "state": (g["received"]["state"], d["sent"]["state"])}
    # Honest image figures: frames whose every strip is fresh, and the fraction of fresh strips. A raw or
    # single-JPEG frame is one piece (whole iff it arrived); a FEC frame is whole or absent.
    if stream_profile(spec.profile).image_mode in ("sliced", "fec") and "image_whole" in g["received"]:
        pairs["image_whole"] = (g["received"]["image_whole"], d["sent"]["image"])
        pairs["image_strip"] = (g["received"]["image_strip"], d["sent"]["image_strip"])
    else:
        pairs["image_whole"] = pairs["image_strip"] = pairs["image"]
    for topic, (received, sent) in pairs.items():
        result["topics"][topic] = analyse(rec(received), rec(sent), t0, t1).as_dict()
    # Copies a starved repeater sent late (together): a gap they explain is the machine's, not the link's.
    result["repeater"] = {"gcs": gcs.get("repeater"), "drone": drone.get("repeater")}
    sp = result["topics"]["setpoint"]
    # Arrivals only (what reached the companion); the flight's own record decides offboard_kept.
    result["setpoint_gap_ok"] = sp["unique"] > 0 and sp["longest_gap_ms"] <= OFFBOARD_GAP_MS
    # A window the senders did not stream through measures their start-up or exit, not the link:
    # every stream then "goes silent" at once at its edge. Say so instead of reporting a gap.
    late = [name for name, sent in (("setpoint", g["sent"]["setpoint"]), ("sensor", d["sent"]["sensor"]))
            if not sent["arrival_ns"] or min(sent["arrival_ns"]) > t0 or max(sent["arrival_ns"]) < t1]
    if late:
        result["invalid"] = f"{', '.join(late)} not sent through the whole window (start-up or exit inside it)"
    return result
