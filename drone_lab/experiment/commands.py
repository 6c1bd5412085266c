"""Command delivery over the lossy link: success rate, latency and double executions per loss level.

``python -m drone_lab.experiment.commands [--loss 0 50 90] [--calls 100] [--timeout 2]
[--transport multicast,unicast] [--monitor]`` (root: it builds the two-namespace veth link of
netns.py). Per loss level and transport, a server process in the drone namespace serves a command
service whose handler counts executions per call id; a client process in the GCS namespace calls
it (``arm``, ``takeoff``, ``hold``, ``land`` in turn) with ``services.command_retry`` (adaptive:
zenoh_robot/services/call_plan.py) and the given deadline. Transports: ``multicast`` is the resilient multicast
session (``SessionConfig.resilient(iface)``, calls ride puts); ``unicast`` is the resilient
peer-to-peer UDP/TCP session the experiment cells build (cell.transport_for, calls ride queries).
``--start after`` switches the loss on only once the caller is linked (a unicast session does
not form from scratch at 90 % loss). ``--monitor`` runs a LossMonitor on both sides feeding
``client.set_loss`` / ``service.set_loss``
(otherwise the plan assumes 50 % loss). Prints a markdown table and, with ``--jsonl FILE``, one
JSON object per level. Bytes per call are payload bytes (requests + reply copies) before Zenoh,
UDP and IP headers (~60 bytes a datagram more).

``--server companion`` measures the same through the real companion (commands_companion.py): the
drone namespace runs ``python -m companion --px4 sim``, the GCS namespace takes control and calls
its ``/uav1/command`` (hold and land in turn: PX4 ACKs and mode changes); per call raw JSONL and a
table under ``docs/results/commands/<--name>/`` (``--report-only NAME`` regenerates the table).
``--loss-model bursty`` (both servers) is netns.py's two-state channel at the same mean.

The same file is both sides of a run: ``... commands serve SESSION [monitor]`` /
``... commands call SESSION N TIMEOUT [monitor]`` (starts calling after a line on stdin), SESSION
being ``multicast:IFACE`` or ``unicast:CONFIG_FILE``.
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
from typing import TYPE_CHECKING, Any

from zenoh_robot import Message, message

from .stall_runs import reap, wait_ready

if TYPE_CHECKING:
    from zenoh_robot import Node, SessionConfig

    from .netns import LossyLink

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


def _wait_transport(node: Node, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(True for _ in node.session.info.transports()):
            return True
        time.sleep(0.05)
    return False


def _session(spec: str) -> SessionConfig | str:
    """``multicast:IFACE`` -> the resilient multicast session; ``unicast:FILE`` -> that config file."""
    from zenoh_robot import SessionConfig
    kind, _, arg = spec.partition(":")
    if kind == "multicast":
        return SessionConfig.resilient(arg)
    if kind == "unicast":
        return arg
    raise ValueError(f"session spec {spec!r}: want multicast:IFACE or unicast:CONFIG_FILE")


MONITOR_SETTLE_S = 2.0    # a LossMonitor's short window is 1 s: let it measure before the first call


def serve(spec: str, monitor: bool = False) -> None:
    """Serve until stdin closes, then print {"executions": {call_id: n}} as JSON."""
    from zenoh_robot import Node
    from zenoh_robot.loss_feedback import LossMonitor
    runs: Counter[int] = Counter()
    lock = threading.Lock()

    def handle(cmd: ExpCommand) -> ExpResult:
        with lock:
            runs[cmd.call_id] += 1
            return ExpResult(True, runs[cmd.call_id])
    with Node("cmd_server", config=_session(spec)) as node:
        srv = node.create_service("exp/command", ExpCommand, ExpResult, handle)
        mon = LossMonitor(node, "drone") if monitor else None
        if mon is not None:
            mon.adapt(srv.set_loss)
        spinner = threading.Thread(target=node.spin, daemon=True)
        spinner.start()
        print("READY", flush=True)
        sys.stdin.readline()
        with lock:
            out = {"executions": dict(runs), "duplicates": srv.duplicates, "cache_evictions": srv.cache_evictions,
                   # getattr: the same tool measures an older library too (its baseline)
                   "reply_copies": getattr(srv, "reply_copies", 0), "reply_bytes": getattr(srv, "reply_bytes", 0)}
        print(json.dumps(out), flush=True)
        if mon is not None:
            mon.close()
        node.shutdown()


def call(spec: str, n: int, timeout: float, monitor: bool = False) -> None:
    """Make ``n`` calls one after the other; print one JSON summary."""
    from zenoh_robot import Node, ServiceCallError
    from zenoh_robot.loss_feedback import LossMonitor
    from zenoh_robot.services import command_retry
    with Node("cmd_client", config=_session(spec)) as node:
        linked = _wait_transport(node, SESSION_WAIT_S)
        sys.stdin.readline()         # GO: the server is serving (run_level sends it)
        client = node.create_client("exp/command", ExpCommand, ExpResult, retry=command_retry(node))
        if not spec.startswith("multicast"):    # unicast: discovery works; count calls, not discovery
            linked = linked and client.wait_for_service(SESSION_WAIT_S)
        print("LINKED", flush=True)
        sys.stdin.readline()         # START: the loss is on (run_level may set it only now)
        mon = LossMonitor(node, "gcs") if monitor else None
        if mon is not None:
            mon.adapt(client.set_loss)
            # The probes' callbacks run on the node's executor (the calls do not need it).
            threading.Thread(target=node.spin, daemon=True).start()
            time.sleep(MONITOR_SETTLE_S)
        loss_seen = getattr(client, "loss", None)
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
        print(json.dumps({"linked": linked, "calls": results, "attempts": client.attempts,
                          "request_bytes": getattr(client, "request_bytes", 0), "loss_estimate": loss_seen}),
              flush=True)
        if mon is not None:
            mon.close()


TRANSPORTS = ("multicast", "unicast")


def _spec(link: LossyLink, side: str, transport: str, workdir: str) -> str:
    if transport == "multicast":
        return f"multicast:{link.dev(side)}"
    from drone_lab.experiment.cell import transport_for
    path = f"{workdir}/{side}.json5"
    with open(path, "w") as f:
        json.dump(transport_for("resilient", link, side, "unicast"), f)
    return f"unicast:{path}"


def run_level(loss_pct: float, calls: int, timeout: float, transport: str = "multicast",
              monitor: bool = False, start: str = "startup", loss_model: str = "uniform") -> dict[str, Any]:
    """One loss level on a fresh lossy link: the summary (success rate, latency, double executions).

    ``start``: "startup", the loss is on from the start (the sessions form under it); "after", it is
    switched on once the caller has its session and (unicast) has discovered the service.
    """
    import tempfile

    from drone_lab.experiment.netns import LossyLink
    if transport not in TRANSPORTS:
        raise ValueError(f"transport {transport!r}: one of {', '.join(TRANSPORTS)}")
    me = [sys.executable, "-m", "drone_lab.experiment.commands"]
    flag = ["monitor"] if monitor else []
    if start not in ("startup", "after"):
        raise ValueError(f"start {start!r}: startup or after")
    initial = loss_pct if start == "startup" else 0.0
    with LossyLink(loss_pct=initial, loss_model=loss_model) as link, \
            tempfile.TemporaryDirectory(prefix="zr-cmd-") as workdir:
        server = subprocess.Popen(link.exec_in("drone") + me + ["serve", _spec(link, "drone", transport, workdir),
                                                                *flag],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        # Both at once: a unicast companion-side open waits until the GCS side listens (cell.transport_for).
        # The caller waits for GO on stdin (the server is serving) before its first call.
        caller = subprocess.Popen(link.exec_in("gcs") + me + ["call", _spec(link, "gcs", transport, workdir),
                                                              str(calls), str(timeout), *flag],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert server.stdout is not None and server.stdin is not None
            if not wait_ready(server):
                raise RuntimeError("command server did not start")
            assert caller.stdin is not None and caller.stdout is not None
            caller.stdin.write("GO\n")
            caller.stdin.flush()
            if not wait_ready(caller, word="LINKED"):
                raise RuntimeError("command caller did not link")
            if start == "after":
                link.set_loss(loss_pct)
            client_out, client_err = caller.communicate("START\n",
                                                        timeout=2 * SESSION_WAIT_S + calls * (timeout + 3) + 30)
            server.stdin.write("\n")
            server.stdin.flush()
            # Zenoh may log lines of its own to stdout: the summary is the first JSON line.
            served = next((json.loads(ln) for ln in iter(server.stdout.readline, "") if ln.startswith("{")), None)
            if served is None:
                raise RuntimeError("command server ended without its summary")
        finally:
            server.stdin.close() if server.stdin else None
            reap(caller, server)
    lines = [ln for ln in client_out.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"command client failed: {client_err[-2000:]}")
    out = json.loads(lines[-1])
    row = summarise(loss_pct, timeout, out, served)
    row["transport"], row["monitor"], row["start"], row["loss_model"] = transport, monitor, start, loss_model
    return row


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
        "reply_copies_per_call": round(served.get("reply_copies", 0) / max(1, len(calls)), 1),
        "bytes_per_call": round((client.get("request_bytes", 0) + served.get("reply_bytes", 0)) / max(1, len(calls))),
        "loss_estimate": client.get("loss_estimate"),
        "double_executions": sum(1 for v in execs.values() if v > 1),
        "executed_but_unanswered": sum(1 for i, c in enumerate(calls) if not c["ok"] and execs.get(i)),
        "server_duplicates": served["duplicates"], "linked": client["linked"],
        "errors": dict(Counter(c["error"] for c in calls if c["error"])),
    }


def table(rows: list[dict[str, Any]]) -> str:
    head = ("| loss each way | transport | calls | answered within deadline | arm / takeoff / hold / land | p50 ms "
            "| p90 ms | max ms | requests per call | reply copies per call | bytes per call | executed twice "
            "| executed, no answer |\n" + "|---" * 13 + "|")
    body = []
    for r in rows:
        pc = " / ".join(f"{r['per_command'][n] * 100:.0f}" for n in NAMES)
        tr = (r.get("transport", "multicast") + (" + monitor" if r.get("monitor") else "")
              + (", loss after link" if r.get("start") == "after" else "")
              + (f", {r['loss_model']}" if r.get("loss_model", "uniform") != "uniform" else ""))
        body.append(f"| {r['loss_pct']:g} % | {tr} | {r['calls']} | {r['success_rate'] * 100:.1f} % "
                    f"(<= {r['timeout_s']:g} s) | {pc} % | {r['latency_ms_p50']} | {r['latency_ms_p90']} "
                    f"| {r['latency_ms_max']} | {r['attempts_per_call']} | {r.get('reply_copies_per_call', '')} "
                    f"| {r.get('bytes_per_call', '')} | {r['double_executions']} | {r['executed_but_unanswered']} |")
    return "\n".join([head, *body])


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "serve":
        serve(argv[1], monitor="monitor" in argv[2:])
        return 0
    if argv and argv[0] == "call":
        call(argv[1], int(argv[2]), float(argv[3]), monitor="monitor" in argv[4:])
        return 0
    p = argparse.ArgumentParser(prog="python -m drone_lab.experiment.commands", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--loss", type=float, nargs="+", default=[0.0, 50.0, 90.0], help="loss %% each way, per level")
    p.add_argument("--calls", type=int, default=100)
    p.add_argument("--timeout", type=float, default=2.0, help="each call's deadline (s)")
    p.add_argument("--transport", default="multicast",
                   help="comma-separated, of: " + ", ".join(TRANSPORTS) + " (default multicast)")
    p.add_argument("--monitor", action="store_true", help="size copies from a LossMonitor's measured loss")
    p.add_argument("--start", choices=("startup", "after"),
                   help="loss from the start (sessions form under it) or only once the caller is linked "
                        "(default: startup for the stub, after for the companion)")
    p.add_argument("--loss-model", default="uniform",
                   help="comma-separated, of: uniform, bursty (netns.py's two-state channel at the same mean)")
    p.add_argument("--burst-mean", type=float, default=0.3, help="bursty: the mean fade, s (companion server)")
    p.add_argument("--server", choices=("stub", "companion"), default="stub",
                   help="stub: a server answering at once; companion: the real companion and its simulator")
    p.add_argument("--gap", type=float, default=1.0,
                   help="companion server: pause before each call, uniform in 0..GAP s (default 1: any phase of "
                        "PX4's 1 Hz heartbeat, which a mode command waits for; 0: back to back)")
    p.add_argument("--name", default=time.strftime("companion-%Y-%m-%d", time.gmtime()),
                   help="companion server: keep the raw data and table in docs/results/commands/NAME/")
    p.add_argument("--report-only", metavar="NAME",
                   help="regenerate docs/results/commands/NAME/table.md from its raw data, run nothing")
    p.add_argument("--jsonl", help="append one JSON object per level here")
    args = p.parse_args(argv)
    if args.report_only:
        from drone_lab.experiment import commands_companion
        directory = commands_companion.RESULTS / args.report_only
        if not any(directory.glob("*.level.json")):
            p.error(f"--report-only: no raw data in {directory}")
        print(commands_companion.write_table(directory, commands_companion.report(directory)))
        return 0
    from drone_lab.experiment.netns import LOSS_MODELS, unavailable_reason
    reason = unavailable_reason()
    if reason:
        print(f"error: {reason}", file=sys.stderr)
        return 2
    transports = [t.strip() for t in args.transport.split(",") if t.strip()]
    bad = [t for t in transports if t not in TRANSPORTS]
    if bad or not transports:
        p.error(f"--transport: unknown {', '.join(bad) or '(none)'}; choose from {', '.join(TRANSPORTS)}")
    models = [m.strip() for m in args.loss_model.split(",") if m.strip()]
    if not models or any(m not in LOSS_MODELS for m in models):
        p.error(f"--loss-model: choose from {', '.join(LOSS_MODELS)}")
    cells = [(t, m, loss) for t in transports for m in models for loss in args.loss]
    if args.server == "companion":
        return _run_companion(args, cells)
    rows = []
    for transport, model, loss in cells:
        row = run_level(loss, args.calls, args.timeout, transport, args.monitor, args.start or "startup", model)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(json.dumps(row) + "\n")
    print(table(rows))
    return 0


def _run_companion(args: argparse.Namespace, cells: list[tuple[str, str, float]]) -> int:
    from drone_lab.experiment import commands_companion
    directory = commands_companion.RESULTS / args.name
    for transport, model, loss in cells:
        t = time.monotonic()
        row = commands_companion.run_level(loss, args.calls, args.timeout, transport, model, args.burst_mean,
                                           args.monitor, args.start or "after", gap_s=args.gap, keep=directory)
        row["wall_s"] = round(time.monotonic() - t, 1)
        print(json.dumps(row), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(json.dumps(row) + "\n")
    # Every level kept in the directory (earlier runs of NAME too), regenerated from the raw data.
    print(commands_companion.write_table(directory, commands_companion.report(directory)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
