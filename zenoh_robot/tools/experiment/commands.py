"""Command delivery over the lossy link: success rate, latency and double executions per loss level.

``python -m zenoh_robot.tools.experiment.commands [--loss 0 50 90] [--calls 100] [--timeout 2]``
(root: it builds the two-namespace veth link of netns.py). Per loss level, a server process in the
drone namespace serves a command service on the resilient multicast session
(``SessionConfig.resilient(iface)``) whose handler counts executions per call id; a client process
in the GCS namespace calls it (``arm``, ``takeoff``, ``hold``, ``land`` in turn) with the library's
default for multicast sessions (``services.RESILIENT_RETRY``) and the given deadline. Prints a
markdown table and, with ``--jsonl FILE``, one JSON object per level.

The same file is both sides of a run: ``... commands serve IFACE`` / ``... commands call IFACE N TIMEOUT``.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import threading
import time
from collections import Counter
from typing import Any

from zenoh_robot import Message, message

NAMES = ("arm", "takeoff", "hold", "land")
SESSION_WAIT_S = 20.0     # a multicast session forms from Join messages: at 90 % loss that can take a while


@message(name="zr_experiment/Command")
class ExpCommand(Message):
    name: str = ""
    call_id: int = 0


@message(name="zr_experiment/CommandResult")
class ExpResult(Message):
    success: bool = False
    executions: int = 0


def _wait_transport(node: Any, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(t.is_multicast for t in node.session.info.transports()):
            return True
        time.sleep(0.05)
    return False


def serve(iface: str) -> None:
    """Serve until stdin closes, then print {"executions": {call_id: n}} as JSON."""
    from zenoh_robot import Node, SessionConfig
    runs: Counter[int] = Counter()
    lock = threading.Lock()

    def handle(cmd: ExpCommand) -> ExpResult:
        with lock:
            runs[cmd.call_id] += 1
            return ExpResult(True, runs[cmd.call_id])
    with Node("cmd_server", config=SessionConfig.resilient(iface)) as node:
        srv = node.create_service("exp/command", ExpCommand, ExpResult, handle)
        spinner = threading.Thread(target=node.spin, daemon=True)
        spinner.start()
        print("READY", flush=True)
        sys.stdin.readline()
        with lock:
            out = {"executions": dict(runs), "duplicates": srv.duplicates, "cache_evictions": srv.cache_evictions}
        print(json.dumps(out), flush=True)
        node.shutdown()


def call(iface: str, n: int, timeout: float) -> None:
    """Make ``n`` calls one after the other; print one JSON summary."""
    from zenoh_robot import Node, ServiceCallError, SessionConfig
    with Node("cmd_client", config=SessionConfig.resilient(iface)) as node:
        linked = _wait_transport(node, SESSION_WAIT_S)
        client = node.create_client("exp/command", ExpCommand, ExpResult)
        results: list[dict[str, Any]] = []
        for i in range(n):
            name = NAMES[i % len(NAMES)]
            t0 = time.monotonic()
            try:
                res = client.call(ExpCommand(name, i), timeout=timeout)
                ok, err = res.success, ""
            except ServiceCallError as exc:
                ok, err = False, type(exc).__name__
            results.append({"name": name, "ok": ok, "latency_s": time.monotonic() - t0, "error": err})
        print(json.dumps({"linked": linked, "calls": results, "attempts": client.attempts}), flush=True)


def run_level(loss_pct: float, calls: int, timeout: float) -> dict[str, Any]:
    """One loss level on a fresh lossy link: the summary (success rate, latency, double executions)."""
    from zenoh_robot.tools.experiment.netns import LossyLink
    me = [sys.executable, "-m", "zenoh_robot.tools.experiment.commands"]
    with LossyLink(loss_pct=loss_pct) as link:
        server = subprocess.Popen(link.exec_in("drone") + me + ["serve", link.dev("drone")],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            assert server.stdout is not None and server.stdin is not None
            if server.stdout.readline().strip() != "READY":
                raise RuntimeError("command server did not start")
            client = subprocess.run(link.exec_in("gcs") + me + ["call", link.dev("gcs"), str(calls), str(timeout)],
                                    capture_output=True, text=True, timeout=SESSION_WAIT_S + calls * (timeout + 3) + 30)
            server.stdin.write("\n")
            server.stdin.flush()
            served = json.loads(server.stdout.readline())
        finally:
            server.stdin.close() if server.stdin else None
            try:
                server.wait(10)
            except subprocess.TimeoutExpired:
                server.kill()
    lines = [ln for ln in client.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"command client failed: {client.stderr[-2000:]}")
    out = json.loads(lines[-1])
    return summarise(loss_pct, timeout, out, served)


def summarise(loss_pct: float, timeout: float, client: dict[str, Any], served: dict[str, Any]) -> dict[str, Any]:
    calls = client["calls"]
    ok = [c for c in calls if c["ok"] and c["latency_s"] <= timeout]
    lat = sorted(c["latency_s"] * 1000 for c in ok)
    execs = {int(k): v for k, v in served["executions"].items()}
    per_name = {name: sum(1 for c in ok if c["name"] == name) / max(1, sum(1 for c in calls if c["name"] == name))
                for name in NAMES}

    def pct(q: float) -> float | None:
        return round(lat[min(len(lat) - 1, int(q * len(lat)))], 1) if lat else None
    return {
        "loss_pct": loss_pct, "timeout_s": timeout, "calls": len(calls), "answered": len(ok),
        "success_rate": len(ok) / max(1, len(calls)), "per_command": per_name,
        "latency_ms_p50": round(statistics.median(lat), 1) if lat else None,
        "latency_ms_p90": pct(0.9), "latency_ms_max": round(lat[-1], 1) if lat else None,
        "attempts_per_call": round(client["attempts"] / max(1, len(calls)), 1),
        "double_executions": sum(1 for v in execs.values() if v > 1),
        "executed_but_unanswered": sum(1 for i, c in enumerate(calls) if not c["ok"] and execs.get(i)),
        "server_duplicates": served["duplicates"], "linked": client["linked"],
    }


def table(rows: list[dict[str, Any]]) -> str:
    head = ("| loss each way | calls | answered within deadline | arm / takeoff / hold / land | p50 ms | p90 ms "
            "| max ms | attempts per call | executed twice | executed, no answer |\n" + "|---" * 10 + "|")
    body = []
    for r in rows:
        pc = " / ".join(f"{r['per_command'][n] * 100:.0f} %" for n in NAMES)
        body.append(f"| {r['loss_pct']:g} % | {r['calls']} | {r['success_rate'] * 100:.1f} % (<= {r['timeout_s']:g} s) "
                    f"| {pc} | {r['latency_ms_p50']} | {r['latency_ms_p90']} | {r['latency_ms_max']} "
                    f"| {r['attempts_per_call']} | {r['double_executions']} | {r['executed_but_unanswered']} |")
    return "\n".join([head, *body])


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "serve":
        serve(argv[1])
        return 0
    if argv and argv[0] == "call":
        call(argv[1], int(argv[2]), float(argv[3]))
        return 0
    p = argparse.ArgumentParser(prog="python -m zenoh_robot.tools.experiment.commands", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--loss", type=float, nargs="+", default=[0.0, 50.0, 90.0], help="loss %% each way, per level")
    p.add_argument("--calls", type=int, default=100)
    p.add_argument("--timeout", type=float, default=2.0, help="each call's deadline (s)")
    p.add_argument("--jsonl", help="append one JSON object per level here")
    args = p.parse_args(argv)
    from zenoh_robot.tools.experiment.netns import unavailable_reason
    reason = unavailable_reason()
    if reason:
        print(f"error: {reason}", file=sys.stderr)
        return 2
    rows = []
    for loss in args.loss:
        row = run_level(loss, args.calls, args.timeout)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(json.dumps(row) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
