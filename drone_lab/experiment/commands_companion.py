"""Commands through the real companion over the lossy link: answered, succeeded, executed once.

``python -m drone_lab.experiment.commands --server companion`` runs this. Per loss level the drone
namespace runs the companion with its built-in simulator (``python -m companion --px4 sim
--profile resilient``, as cell.py starts it; camera off, its load is not what is measured); the GCS
namespace runs a caller (``python -m drone_lab.experiment.commands_companion call ...``) that takes
control (``take_control``) and then makes N calls of the companion's real command service
(``/uav1/command``, drone_contract's ``Command``) with ``services.command_retry`` and a deadline,
cycling commands that go to PX4 and wait for its ACK and its heartbeat showing the mode, yet are
safe on the ground and repeatable: ``hold`` (DO_SET_MODE AUTO.LOITER) and ``land`` (AUTO.LAND).

Each call carries its index in ``Command.value`` (unused by hold and land), so the companion's
log line ``command hold (value=17 ...)`` names the call: a call id logged twice (not counting a
``busy`` refusal, which is not cached and so is retried) is a double execution. PX4's side is the
companion's vehicle record (the mode PX4's heartbeat reports, every 20 ms): its mode changes in
the window are the commands PX4 carried out.

Raw data per level, kept under ``docs/results/commands/<name>/``: ``<label>.calls.jsonl`` (one
line per call), ``<label>.level.json`` (the level, the channel applied, bytes, what the companion
executed, PX4's mode changes), ``<label>.companion.log``; ``table.md`` is regenerated from them
(``--report-only``).
"""
from __future__ import annotations

import json
import math
import random
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

from .cell import DRONE_ID, _default_sigint, _stop, _wait_log, transport_for
from .commands import SESSION_WAIT_S, _wait_transport
from .netns import BurstModel, LossyLink

CYCLE = ("hold", "land")
EXPECTED_MODE = {"hold": "AUTO.LOITER", "land": "AUTO.LAND", "rtl": "AUTO.RTL", "offboard_stop": "AUTO.LOITER"}
CLIENT_ID = "gcs-cmd-exp"
CONTROL_WAIT_S = 30.0     # take_control retried until answered (the loss may already be on: --start startup)
STARTUP_TIMEOUT_S = 60.0  # launch -> the companion has its PX4 (6-11 s on a loaded 2-core machine)
RESULTS = Path("docs/results/commands")
# A GCS's commands come at any phase of PX4's 1 Hz heartbeat, which a mode command waits for (px4_link's
# set_mode confirms the switch by it): back to back, every call would wait the whole period.
GAP_S = 1.0
TRANSPORT_CELL = {"multicast": "default", "unicast": "unicast"}   # this tool's names -> cell.transport_for's


# -- the GCS side (a process in the GCS namespace) ------------------------------------------------
def call(config: str, n: int, timeout: float, cycle: list[str], gap_s: float, monitor: bool = False) -> None:
    """Take control, print ``LINKED {json}``, wait for START on stdin, then make ``n`` calls, each after a
    pause drawn uniformly in 0..``gap_s``, printing ``CALL {json}`` per call and one summary JSON line."""
    from drone_contract.commands import COMMAND_SERVICE
    from drone_contract.messages import Command, CommandResult
    from zenoh_robot import Node, ServiceCallError
    from zenoh_robot.loss_feedback import LossMonitor
    from zenoh_robot.services import command_retry
    with Node("cmd_gcs", config=config) as node:
        linked = _wait_transport(node, SESSION_WAIT_S)
        client = node.create_client(f"/{DRONE_ID}/{COMMAND_SERVICE}", Command, CommandResult,
                                    retry=command_retry(node))
        control, t_ctl = "", time.monotonic()
        while not control.startswith("ok") and time.monotonic() - t_ctl < CONTROL_WAIT_S:
            try:
                res = client.call(Command("take_control", client_id=CLIENT_ID), timeout=3.0)
                control = ("ok " if res.success else "refused ") + res.message
            except ServiceCallError as exc:
                control = f"{type(exc).__name__}: {exc}"
        print("LINKED " + json.dumps({"linked": linked, "control": control,
                                      "control_s": round(time.monotonic() - t_ctl, 3)}), flush=True)
        sys.stdin.readline()          # START: the loss is on
        mon = LossMonitor(node, "gcs") if monitor else None
        if mon is not None:           # as the GCS app does: retries and reply copies sized from the measured loss
            mon.adapt(client.set_loss)
            threading.Thread(target=node.spin, daemon=True).start()
            time.sleep(2.0)           # the monitor's short window is 1 s
        attempts0, bytes0 = client.attempts, getattr(client, "request_bytes", 0)
        pauses = random.Random(n)    # the same pauses in every level
        for i in range(n):
            name = cycle[i % len(cycle)]
            gap = pauses.uniform(0.0, gap_s)
            time.sleep(gap)
            row: dict[str, Any] = {"i": i, "name": name, "gap_s": round(gap, 3), "t_ns": time.time_ns()}
            t0 = time.monotonic()
            try:
                res = client.call(Command(name, float(i), client_id=CLIENT_ID), timeout=timeout)
                row.update(answered=True, success=res.success, message=res.message[:200], mode=res.mode, error="")
            except ServiceCallError as exc:
                row.update(answered=False, success=False, message=str(exc)[:200], mode="", error=type(exc).__name__)
            row["latency_s"] = round(time.monotonic() - t0, 4)
            print("CALL " + json.dumps(row), flush=True)
        loss = getattr(client, "loss", None)     # NaN when nothing measured: no JSON
        print(json.dumps({"attempts": client.attempts - attempts0,
                          "request_bytes": getattr(client, "request_bytes", 0) - bytes0,
                          "loss_estimate": loss if loss is None or math.isfinite(loss) else None}), flush=True)
        if mon is not None:
            mon.close()


# -- one level -------------------------------------------------------------------------------------
def level_label(transport: str, loss_model: str, loss_pct: float, monitor: bool) -> str:
    return f"{transport}-{loss_model}-{loss_pct:g}" + ("-monitor" if monitor else "")


def run_level(loss_pct: float, calls: int, timeout: float, transport: str = "multicast",
              loss_model: str = "uniform", burst_mean_s: float = 0.3, monitor: bool = False,
              start: str = "after", cycle: tuple[str, ...] = CYCLE, gap_s: float = GAP_S,
              keep: Path | None = None) -> dict[str, Any]:
    """One loss level on a fresh lossy link; returns the summary row. ``keep``: a directory for the raw data.

    ``start``: "after", the loss comes on once the caller holds control and the companion has its PX4
    (what is measured is the calls); "startup", it is on from the launch (control is taken across it)."""
    if transport not in TRANSPORT_CELL:
        raise ValueError(f"transport {transport!r}: one of {', '.join(TRANSPORT_CELL)}")
    if start not in ("startup", "after"):
        raise ValueError(f"start {start!r}: startup or after")
    label = level_label(transport, loss_model, loss_pct, monitor)
    with tempfile.TemporaryDirectory(prefix="zr-cmdc-") as tmp, \
            LossyLink(loss_pct=loss_pct if start == "startup" else 0.0, loss_model=loss_model,
                      burst=BurstModel(bad_mean_s=burst_mean_s)) as link:
        work = Path(tmp)
        for side in link.sides:
            (work / f"{side}.json5").write_text(json.dumps(transport_for("resilient", link, side,
                                                                         TRANSPORT_CELL[transport])))
        backstop = STARTUP_TIMEOUT_S + CONTROL_WAIT_S + calls * (timeout + gap_s + 3) + 60
        drone_cmd = [sys.executable, "-m", "companion", "--id", DRONE_ID, "--px4", "sim", "--profile", "resilient",
                     "--camera", "none", "--zenoh", str(work / "drone.json5"), "--record", str(work / "drone.json"),
                     "--vehicle-record", str(work / "vehicle.jsonl"), "--duration", str(backstop)]
        caller_cmd = [sys.executable, "-m", "drone_lab.experiment.commands_companion", "call",
                      str(work / "gcs.json5"), str(calls), str(timeout), ",".join(cycle), str(gap_s),
                      *(["monitor"] * monitor)]
        drone_log = open(work / "drone.log", "w")
        companion = subprocess.Popen(link.exec_in("drone") + drone_cmd, stdout=drone_log, stderr=subprocess.STDOUT,
                                     preexec_fn=_default_sigint)
        caller_err = open(work / "gcs.err", "w")    # a file, not a pipe nobody drains while the calls run
        caller = subprocess.Popen(link.exec_in("gcs") + caller_cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=caller_err, text=True)
        rows: list[dict[str, Any]] = []
        try:
            assert caller.stdin is not None and caller.stdout is not None
            if _wait_log(work / "drone.log", f"companion {DRONE_ID}: PX4 at", {"drone": companion},
                         STARTUP_TIMEOUT_S) is None:
                raise RuntimeError(f"companion did not start: {(work / 'drone.log').read_text()[-2000:]}")
            linked = _read_prefixed(caller.stdout, "LINKED ")
            if linked is None:
                raise RuntimeError(f"caller did not link: {(work / 'gcs.err').read_text()[-2000:]}")
            if start == "after":
                link.set_loss(loss_pct)
            tx0 = {side: link.tx_bytes(side) for side in link.sides}
            t0 = time.time_ns()
            caller.stdin.write("START\n")
            caller.stdin.flush()
            out = ""
            for line in iter(caller.stdout.readline, ""):   # Zenoh may log lines of its own: keep ours
                if line.startswith("CALL "):
                    rows.append(json.loads(line[5:]))
                elif line.startswith("{"):
                    out = line
                    break
            t1 = time.time_ns()
            tx1 = {side: link.tx_bytes(side) for side in link.sides}
            channel = link.timeline_summary(t0, t1)
            link.set_loss(0)
            caller.wait(30)
            if not out:
                raise RuntimeError(f"caller ended without its summary: {(work / 'gcs.err').read_text()[-2000:]}")
            _stop({"drone": companion}, timeout=30.0)     # Ctrl-C: it writes its record on the way out
        finally:
            for p in (caller, companion):
                if p.poll() is None:
                    p.kill()
                    p.wait(10)
            drone_log.close()
            caller_err.close()
        log_text = (work / "drone.log").read_text(errors="replace")
        level = {
            "label": label, "loss_pct": loss_pct, "loss_model": loss_model, "burst_mean_s": burst_mean_s,
            "transport": transport, "monitor": monitor, "start": start, "timeout_s": timeout, "cycle": list(cycle),
            "calls_asked": calls, "gap_s": gap_s, "window_ns": [t0, t1], "channel": channel,
            "tx_bytes": {side: tx1[side] - tx0[side] for side in tx0}, "caller": {**linked, **json.loads(out)},
            "companion": {**companion_executions(log_text, cycle), **_companion_record(work / "drone.json"),
                          "exit_code": companion.returncode},
            "px4_modes": mode_changes(work / "vehicle.jsonl", t0),
        }
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            (keep / f"{label}.calls.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
            (keep / f"{label}.level.json").write_text(json.dumps(level, indent=1))
            (keep / f"{label}.companion.log").write_text(log_text)
    return summarise(level, rows)


def _read_prefixed(stream: Any, prefix: str, max_lines: int = 200) -> dict[str, Any] | None:
    for _ in range(max_lines):
        line = stream.readline()
        if not line:
            return None
        if line.startswith(prefix):
            data: dict[str, Any] = json.loads(line[len(prefix):])
            return data
    return None


# -- what the companion and PX4 did ------------------------------------------------------------------
_COMMAND_LINE = re.compile(r"\bcommand (\w+) \(value=([-+.\deinf]+) ")
_BUSY_LINE = re.compile(r"\bcommand (\w+) from \S+ refused or failed: busy")


def companion_executions(log_text: str, cycle: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """Per call id, how often the companion's command desk ran it (its log), less ``busy`` refusals
    (refused before running; not cached, so the client's retry comes back as a new request)."""
    runs: Counter[int] = Counter()
    busy: Counter[int] = Counter()
    last: dict[str, int] = {}
    for line in log_text.splitlines():
        m = _COMMAND_LINE.search(line)
        if m and m.group(1) in cycle:
            i = int(float(m.group(2)))
            runs[i] += 1
            last[m.group(1)] = i
            continue
        b = _BUSY_LINE.search(line)
        if b and b.group(1) in last:   # the executor logs the refusal right after its command line
            busy[last[b.group(1)]] += 1
    return {"executions": {str(i): runs[i] - busy[i] for i in sorted(runs)},
            "busy": {str(i): n for i, n in sorted(busy.items())}}


def _companion_record(path: Path) -> dict[str, Any]:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return {"record": None}
    return {"px4_worker": rec.get("px4_worker"), "commands_refused": rec.get("commands_refused"),
            "final_mode": rec.get("final_mode"), "failsafe": rec.get("failsafe")}


def mode_changes(vehicle_record: Path, t0_ns: int) -> list[tuple[int, str]]:
    """PX4's mode as its heartbeat reported it (the companion's vehicle record): (t ns, mode) at the
    window's start and at each change after it, to the record's end (the last call's reply may come
    before the record's next sample; no call is made after the window)."""
    changes: list[tuple[int, str]] = []
    try:
        lines = vehicle_record.read_text().splitlines()
    except OSError:
        return changes
    for line in lines:
        try:
            s = json.loads(line)
        except ValueError:
            continue      # the last line may be cut by the stop
        if s["t"] < t0_ns:
            changes[:] = [(t0_ns, s["mode"])]
        elif not changes or changes[-1][1] != s["mode"]:
            changes.append((s["t"], s["mode"]))
    return changes


# -- figures -------------------------------------------------------------------------------------------
def summarise(level: dict[str, Any], rows: list[dict[str, Any]]) -> dict[str, Any]:
    timeout = level["timeout_s"]
    n = len(rows)
    answered = [r for r in rows if r["answered"] and r["latency_s"] <= timeout]
    success = [r for r in answered if r["success"]]
    lat = sorted(r["latency_s"] * 1000 for r in answered)
    execs = {int(k): v for k, v in level["companion"]["executions"].items()}
    window_s = max(1e-9, (level["window_ns"][1] - level["window_ns"][0]) / 1e9)

    def pct(q: float) -> float | None:
        return round(lat[min(len(lat) - 1, int(q * len(lat)))], 1) if lat else None
    caller = level["caller"]
    return {
        "label": level["label"], "loss_pct": level["loss_pct"], "loss_model": level["loss_model"],
        "transport": level["transport"], "monitor": level["monitor"], "start": level["start"],
        "timeout_s": timeout, "calls": n, "cycle": level["cycle"],
        "answered_pct": round(100 * len(answered) / max(1, n), 1),
        "success_pct": round(100 * len(success) / max(1, n), 1),
        "refused_in_time": len(answered) - len(success),
        "refusals": dict(Counter(r["message"][:60] for r in answered if not r["success"])),
        # The reply's mode is PX4's heartbeat after the handler: the mode the command asked for.
        "mode_confirmed": sum(1 for r in success if r["mode"] == EXPECTED_MODE.get(r["name"])),
        "latency_ms_p50": round(statistics.median(lat), 1) if lat else None,
        "latency_ms_p90": pct(0.9), "latency_ms_p99": pct(0.99), "latency_ms_max": round(lat[-1], 1) if lat else None,
        "px4_mode_changes": max(0, len(level["px4_modes"]) - 1),
        "executed": sum(1 for v in execs.values() if v > 0),
        "double_executions": sum(1 for v in execs.values() if v > 1),
        "executed_but_unanswered": sum(1 for r in rows if not r["answered"] and execs.get(r["i"], 0) > 0),
        "busy_refusals": sum(level["companion"]["busy"].values()),
        "attempts_per_call": round(caller["attempts"] / max(1, n), 1),
        "request_bytes_per_call": round(caller["request_bytes"] / max(1, n)),
        # Everything on the veth in the window (telemetry and state too), not only the calls.
        "link_kBps": {side: round(b / 1000 / window_s, 1) for side, b in level["tx_bytes"].items()},
        "window_s": round(window_s, 1), "applied_loss_pct": level["channel"].get("mean_pct"),
        "bad_periods": level["channel"].get("bad_periods"), "linked": caller["linked"],
        "control": caller["control"], "errors": dict(Counter(r["error"] for r in rows if r["error"])),
    }


def table(rows: list[dict[str, Any]]) -> str:
    head = ("| loss each way | model (applied) | transport | calls | answered within deadline | succeeded "
            "| refused in time | p50 ms | p90 ms | p99 ms | max ms | PX4 mode changes | executed twice "
            "| executed, no answer | requests per call | request bytes per call | link kB/s GCS / drone | window s |\n"
            + "|---" * 18 + "|")
    body = []
    for r in rows:
        model = f"{r['loss_model']} ({r['applied_loss_pct']} %" + (
            f", {r['bad_periods']} fades)" if r["loss_model"] == "bursty" else ")")
        tr = r["transport"] + (" + monitor" if r["monitor"] else "") + (", loss from start-up"
                                                                       if r["start"] == "startup" else "")
        kb = r["link_kBps"]
        body.append(f"| {r['loss_pct']:g} % | {model} | {tr} | {r['calls']} | {r['answered_pct']:.1f} % "
                    f"(<= {r['timeout_s']:g} s) | {r['success_pct']:.1f} % | {r['refused_in_time']} "
                    f"| {r['latency_ms_p50']} | {r['latency_ms_p90']} | {r['latency_ms_p99']} | {r['latency_ms_max']} "
                    f"| {r['px4_mode_changes']} | {r['double_executions']} | {r['executed_but_unanswered']} "
                    f"| {r['attempts_per_call']} | {r['request_bytes_per_call']} | {kb.get('gcs')} / {kb.get('drone')} "
                    f"| {r['window_s']} |")
    return "\n".join([head, *body])


def report(directory: Path) -> list[dict[str, Any]]:
    """The summary rows regenerated from the raw data kept in ``directory``, in the order they ran."""
    rows = []
    for path in sorted(directory.glob("*.level.json"), key=lambda p: json.loads(p.read_text())["window_ns"][0]):
        level = json.loads(path.read_text())
        calls_path = directory / f"{level['label']}.calls.jsonl"
        calls = [json.loads(x) for x in calls_path.read_text().splitlines() if x.strip()]
        rows.append(summarise(level, calls))
    return rows


def write_table(directory: Path, rows: list[dict[str, Any]]) -> str:
    text = (f"# Commands through the real companion ({directory.name})\n\n"
            "Regenerated from the raw data here by `python -m drone_lab.experiment.commands --report-only "
            f"{directory.name}`; columns in docs/lossy-link.md (Commands through the real companion).\n\n"
            + table(rows) + "\n")
    (directory / "table.md").write_text(text)
    return text


def main(argv: list[str]) -> int:
    if argv and argv[0] == "call":
        call(argv[1], int(argv[2]), float(argv[3]), argv[4].split(","), float(argv[5]), monitor="monitor" in argv[6:])
        return 0
    print("usage: python -m drone_lab.experiment.commands --server companion ...", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
