"""The replay attack of issue #37, flown: record a sealed flight off the link, restart an end, replay it.

An attacker with a radio (a plain zenoh-python session on the link: in the GCS's namespace, on the
resilient profile's multicast group or as a client of the ground router) records everything a sealed
mission sends: the GCS's setpoints, presence and command calls (``offboard_start``, ``arm``, ...), the
drone's telemetry. Then, each time against the vehicle sitting on the ground, disarmed:

1. ``running``: replayed into the companion that saw the flight (its replay windows are in memory);
2. ``companion restarted``: the companion restarted (a reboot, a battery swap), the same recording;
3. ``gcs restarted``: a new GCS process flew a second mission and exited; its recording replayed.

After (2) the legitimate GCS must still fly a mission. Each replay must leave the vehicle's mode,
arming and position as they were (the companion's ``--vehicle-record``), and the companion's summary
(``--record``) must count the refusals by reason (``link_refused``). Both apps run sealed
(``--link-keys``) on the resilient profile, over the nftables loss of ``netns.LossyLink`` (through the
router, the companion's session forms before the loss is applied: docs/lossy-link.md's start-up limit).

    python -m drone_lab.experiment.replay_attack --out DIR [--losses 0,50] [--transports multicast,router] [--runs 3]

writes ``DIR/replay.jsonl`` (one line a cell and run) and ``DIR/cells/<cell>/`` (every app's log and
record, the two recordings). Root only (network namespaces).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from .cell import DRONE_ID, _default_sigint, _start_router, _wait_log, transport_for
from .netns import LossyLink
from .secure_sweep import LINK_KEYS_ENV, make_cell_link_keys

STARTUP_TIMEOUT_S = 60.0
MISSION_TIMEOUT_S = 120.0
REPLAY_SPEEDUP = 4.0         # a recording replayed 4x faster than it was sent: every sample, sooner
SETTLE_S = 2.0               # after a replay: time for a replayed command to have acted (PX4 answers in ms)
MOVED_M = 0.3                # the vehicle "moved" if its position changed more than this


@dataclasses.dataclass(frozen=True)
class ReplayCell:
    loss: float = 0.0
    transport: str = "multicast"     # multicast | router
    pattern_s: float = 2.0           # the missions' pattern: short, the recording needs only their calls
    altitude_m: float = 3.0

    @property
    def label(self) -> str:
        return f"{self.transport}-{self.loss:g}"


# -- the attacker: a plain session that records and replays ----------------------------------------
def _plain_session(config_path: Path) -> Any:
    import zenoh
    return zenoh.open(zenoh.Config.from_json5(config_path.read_text()))


def record(config_path: Path, out: Path, stop_file: Path) -> None:
    """Every sample on the link (``**``), with its arrival time, to ``out`` (msgpack), until ``stop_file``."""
    import msgpack
    lock = threading.Lock()
    samples: list[tuple[float, str, bytes, bytes | None]] = []

    def on_sample(s: Any) -> None:
        att = s.attachment.to_bytes() if s.attachment is not None else None
        with lock:
            samples.append((time.monotonic(), str(s.key_expr), s.payload.to_bytes(), att))
    session = _plain_session(config_path)
    sub = session.declare_subscriber("**", on_sample)
    print("recording", flush=True)
    while not stop_file.exists():
        time.sleep(0.05)
    sub.undeclare()
    session.close()
    with lock:
        out.write_bytes(msgpack.packb(samples))
    print(f"recorded {len(samples)} samples", flush=True)


def replay(config_path: Path, recording: Path, speedup: float) -> None:
    """Put every recorded sample again, on its key, ``speedup`` times faster than it was heard."""
    import msgpack
    samples = msgpack.unpackb(recording.read_bytes())
    session = _plain_session(config_path)
    time.sleep(1.0)     # the session's links and declarations up before the first put
    t0, start = (samples[0][0] if samples else 0.0), time.monotonic()
    for at, key, payload, att in samples:
        delay = (at - t0) / speedup - (time.monotonic() - start)
        if delay > 0:
            time.sleep(delay)
        session.put(key, payload, attachment=att)
    time.sleep(0.5)
    session.close()
    print(f"replayed {len(samples)} samples", flush=True)


# -- one cell ----------------------------------------------------------------------------------------
class _Cell:
    def __init__(self, cell: ReplayCell, link: LossyLink, workdir: Path) -> None:
        self.cell, self.link, self.workdir = cell, link, workdir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def _spawn(self, name: str, side: str, cmd: list[str]) -> subprocess.Popen[bytes]:
        log = open(self.workdir / f"{name}.log", "w")
        proc = subprocess.Popen(self.link.exec_in(side) + cmd, stdout=log, stderr=subprocess.STDOUT,
                                preexec_fn=_default_sigint)
        self.procs[name] = proc
        return proc

    def companion(self, name: str) -> subprocess.Popen[bytes]:
        """Start a companion and wait for its session and PX4. Through the router its session forms
        without loss (from start-up at 50 % a client's session often never forms: docs/lossy-link.md),
        and the cell's loss is back before anything else happens."""
        if self.cell.transport == "router":
            self.link.set_loss(0.0)
        try:
            return self._start_companion(name)
        finally:
            self.link.set_loss(self.cell.loss)

    def _start_companion(self, name: str) -> subprocess.Popen[bytes]:
        cmd = [sys.executable, "-m", "companion", "--id", DRONE_ID, "--px4", "sim", "--profile", "resilient",
               "--zenoh", str(self.workdir / "drone.json5"), "--record", str(self.workdir / f"{name}.json"),
               "--vehicle-record", str(self.workdir / f"{name}.vehicle.jsonl"), "--duration", "600"]
        proc = self._spawn(name, "drone", cmd)
        if _wait_log(self.workdir / f"{name}.log", f"companion {DRONE_ID}: PX4 at", {name: proc},
                     STARTUP_TIMEOUT_S) is None:
            raise RuntimeError(f"{name} did not start (see {self.workdir / name}.log)")
        return proc

    def mission(self, name: str) -> dict[str, Any]:
        cmd = [sys.executable, "-m", "gcs", "--drones", DRONE_ID, "--no-dashboard", "--mission", "--insecure-ok",
               "--pattern", "hover", "--altitude", str(self.cell.altitude_m), "--duration", str(self.cell.pattern_s),
               "--profile", "resilient", "--zenoh", str(self.workdir / "gcs.json5"),
               "--record", str(self.workdir / f"{name}.json")]
        proc = self._spawn(name, "gcs", cmd)
        try:
            rc = proc.wait(timeout=MISSION_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)
            rc = proc.wait(timeout=30)
        text = (self.workdir / f"{name}.log").read_text(errors="replace")
        return {"rc": rc, "ok": rc == 0 and "mission ok" in text}

    def recorded_mission(self, name: str, recording: Path) -> dict[str, Any]:
        """A mission flown while the attacker records it to ``recording``; returns once the vehicle has
        landed and disarmed and the recording is on disk."""
        stop_file = recording.with_suffix(".stop")
        rec = self.attacker("record", recording, stop_file)
        _wait_log(self.workdir / f"attacker-record-{recording.stem}.log", "recording", {"rec": rec}, 30.0)
        time.sleep(1.0)
        outcome = self.mission(name)
        stop_file.touch()
        rec.wait(timeout=60)
        time.sleep(SETTLE_S)     # landed and disarmed before a replay
        return outcome

    def attacker(self, verb: str, recording: Path, stop_file: Path | None = None) -> subprocess.Popen[bytes]:
        cmd = [sys.executable, "-m", "drone_lab.experiment.replay_attack", verb, "--zenoh",
               str(self.workdir / "attacker.json5"), "--file", str(recording)]
        if stop_file is not None:
            cmd += ["--stop-file", str(stop_file)]
        return self._spawn(f"attacker-{verb}-{recording.stem}", "gcs", cmd)

    def stop(self, name: str, timeout: float = 20.0) -> int | None:
        proc = self.procs[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return proc.returncode

    def stop_all(self) -> None:
        for name, proc in self.procs.items():
            if proc.poll() is None:
                self.stop(name, timeout=10.0)


def vehicle_lines(path: Path) -> list[dict[str, Any]]:
    lines = []
    for line in path.read_text(errors="replace").splitlines():
        try:
            lines.append(json.loads(line))
        except ValueError:
            pass    # the last line, cut by the exit
    return lines


def vehicle_moved(lines: list[dict[str, Any]], t0_ns: int, t1_ns: int) -> dict[str, Any]:
    """What the vehicle did in ``[t0_ns, t1_ns]`` (wall ns): armed, modes, how far it moved."""
    window = [ln for ln in lines if t0_ns <= ln["t"] <= t1_ns]
    before = [ln for ln in lines if ln["t"] < t0_ns]
    ref = (before[-1] if before else window[0]) if (before or window) else None
    if ref is None:
        return {"samples": 0}
    positions = [ln["pos"] for ln in window if ln.get("pos")]
    p0 = ref.get("pos") or (positions[0] if positions else None)
    moved = None if not p0 else max(
        (sum((a - b) ** 2 for a, b in zip(p, p0, strict=True)) ** 0.5 for p in positions), default=0.0)
    return {"samples": len(window), "mode_before": ref["mode"], "modes": sorted({ln["mode"] for ln in window}),
            "armed_before": ref["armed"], "ever_armed": any(ln["armed"] for ln in window),
            "sessions": sorted({ln["session"] for ln in window}), "moved_m": moved}


def untouched(effect: dict[str, Any]) -> bool:
    """The replay left the vehicle as it was: same mode throughout, never armed, not moved."""
    return (effect.get("samples", 0) > 0 and effect["modes"] == [effect["mode_before"]]
            and not effect["armed_before"] and not effect["ever_armed"] and effect["sessions"] == ["idle"]
            and effect["moved_m"] is not None and effect["moved_m"] < MOVED_M)


def _replay_into(c: _Cell, recording: Path, vehicle: Path) -> dict[str, Any]:
    t0 = time.time_ns()
    proc = c.attacker("replay", recording)
    proc.wait(timeout=300)
    time.sleep(SETTLE_S)
    t1 = time.time_ns()
    effect = vehicle_moved(vehicle_lines(vehicle), t0, t1)
    effect["untouched"] = untouched(effect)
    effect["replayer_rc"] = proc.returncode
    return effect


def _attacker_config(cell: ReplayCell, link: LossyLink) -> dict[str, Any]:
    """The attacker's session: the GCS's own transport config (what its radio hears and speaks)."""
    cfg = transport_for("resilient", link, "gcs", "router" if cell.transport == "router" else "default")
    return cfg


def run_replay_cell(cell: ReplayCell, workdir: Path, link_keys: Path, log: Any = print) -> dict[str, Any]:
    """The three replays of the module doc in one cell; the result names each one's effect and the
    companions' refusal counts. ``error`` says what kept a step from running."""
    workdir.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"cell": cell.label, "loss": cell.loss, "transport": cell.transport}
    old_env = os.environ.get(LINK_KEYS_ENV)
    os.environ[LINK_KEYS_ENV] = str(link_keys)
    try:
        with LossyLink(loss_pct=cell.loss) as link:
            transport = "router" if cell.transport == "router" else "default"
            for side in ("gcs", "drone"):
                (workdir / f"{side}.json5").write_text(json.dumps(transport_for("resilient", link, side, transport)))
            (workdir / "attacker.json5").write_text(json.dumps(_attacker_config(cell, link)))
            c = _Cell(cell, link, workdir)
            try:
                if cell.transport == "router":
                    c.procs["router"] = _start_router(link, workdir)
                c.companion("companion1")
                flight1 = workdir / "flight1.msgpack"
                result["mission1"] = c.recorded_mission("gcs1", flight1)
                log(f"  {cell.label}: mission 1 {'ok' if result['mission1']['ok'] else 'FAILED'}")
                result["replay_running"] = _replay_into(c, flight1, workdir / "companion1.vehicle.jsonl")
                log(f"  {cell.label}: replay into the running companion: {result['replay_running']}")
                c.stop("companion1")
                c.companion("companion2")
                time.sleep(1.0)
                result["replay_companion_restarted"] = _replay_into(c, flight1, workdir / "companion2.vehicle.jsonl")
                log(f"  {cell.label}: replay after the companion restarted: {result['replay_companion_restarted']}")
                flight2 = workdir / "flight2.msgpack"
                result["mission2"] = c.recorded_mission("gcs2", flight2)
                log(f"  {cell.label}: mission 2 (after the replays) {'ok' if result['mission2']['ok'] else 'FAILED'}")
                result["replay_gcs_restarted"] = _replay_into(c, flight2, workdir / "companion2.vehicle.jsonl")
                log(f"  {cell.label}: replay of the second GCS's flight: {result['replay_gcs_restarted']}")
                c.stop("companion2")
            finally:
                c.stop_all()
    except Exception as exc:
        result["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        if old_env is None:
            os.environ.pop(LINK_KEYS_ENV, None)
        else:
            os.environ[LINK_KEYS_ENV] = old_env
    for name in ("companion1", "companion2"):
        try:
            summary = json.loads((workdir / f"{name}.json").read_text())
            result[f"{name}_refused"] = summary.get("link_refused")
        except (OSError, ValueError):
            result[f"{name}_refused"] = None
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m drone_lab.experiment.replay_attack", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="verb")
    for verb in ("record", "replay"):
        v = sub.add_parser(verb, help=f"(the attacker's process) {verb} samples")
        v.add_argument("--zenoh", type=Path, required=True)
        v.add_argument("--file", type=Path, required=True)
        v.add_argument("--stop-file", type=Path)
        v.add_argument("--speedup", type=float, default=REPLAY_SPEEDUP)
    p.add_argument("--out", type=Path)
    p.add_argument("--losses", default="0,50")
    p.add_argument("--transports", default="multicast,router")
    p.add_argument("--runs", type=int, default=1)
    args = p.parse_args(argv)
    if args.verb == "record":
        if args.stop_file is None:
            p.error("record needs --stop-file")
        record(args.zenoh, args.file, args.stop_file)
        return 0
    if args.verb == "replay":
        replay(args.zenoh, args.file, args.speedup)
        return 0
    if args.out is None:
        p.error("--out DIR is needed to run the cells")
    try:
        losses = [float(x) for x in args.losses.split(",") if x]
    except ValueError:
        p.error(f"--losses {args.losses!r}: expected numbers, e.g. 0,50")
    transports = [t for t in args.transports.split(",") if t]
    bad = [t for t in transports if t not in ("multicast", "router")]
    if bad:
        p.error(f"--transports: {', '.join(bad)} (expected multicast, router)")
    args.out.mkdir(parents=True, exist_ok=True)
    failed = 0
    with tempfile.TemporaryDirectory(prefix="zr-replay-keys-") as tmp:
        link_keys = make_cell_link_keys(Path(tmp))
        with (args.out / "replay.jsonl").open("a") as out:
            for run in range(args.runs):
                for transport in transports:
                    for loss in losses:
                        cell = ReplayCell(loss, transport)
                        print(f"cell {cell.label} run {run + 1}/{args.runs}", flush=True)
                        r = run_replay_cell(cell, args.out / "cells" / f"{cell.label}-r{run}", link_keys)
                        r["run"] = run
                        out.write(json.dumps(r) + "\n")
                        out.flush()
                        ok = not r.get("error") and all(r.get(k, {}).get("untouched") for k in REPLAYS) \
                            and r.get("mission2", {}).get("ok")
                        failed += not ok
                        print(f"cell {cell.label} run {run + 1}: {'held' if ok else 'FAILED'}", flush=True)
    return 1 if failed else 0


REPLAYS = ("replay_running", "replay_companion_restarted", "replay_gcs_restarted")

if __name__ == "__main__":
    sys.exit(main())
