"""ROS 2 actions over the lossy link: goals accepted, results received, cancels honoured, none run twice.

``python -m drone_lab.experiment.actions_lossy [--loss 50] [--goals 20] [--accept-timeout 5]
[--result-timeout 10]`` (root: it builds the two-namespace veth link of netns.py, the loss on from
start-up). Per loss level, an action server process in the drone namespace serves
``example_interfaces/action/Fibonacci`` on the envelope wire, with the resilient multicast session
commands.py's server uses (``SessionConfig.resilient(iface)``: the three action services ride
put-carried calls with AdaptiveRetry, the feedback and status topics best-effort puts). Its execute
callback records every execution of each goal id (a second one is a double execution) and:

- a fast goal (order < :data:`SLOW_ORDER`): :data:`FEEDBACKS` feedback messages ~50 ms apart, then succeeds;
- a slow goal (order >= :data:`SLOW_ORDER`): feedback every 50 ms for :data:`SLOW_S`, canceled as soon
  as a cancel is requested (its cancel_callback accepts), else succeeds.

A client process in the GCS namespace sends N goals one after the other (each with a goal id of its
own): acceptance within ``--accept-timeout`` (the action client's ``goal_timeout``: the send_goal and
cancel_goal calls' deadline), the result within ``--result-timeout`` (the client's get_result is
re-asked every :data:`RESULT_POLL_S`). Goal 0 is a slow goal nobody cancels (its result comes after
more than one get_result poll); every :data:`CANCEL_EVERY`-th goal from 2 on is a slow goal canceled
:data:`CANCEL_AFTER_S` after its acceptance; every :data:`RESEND_EVERY`-th goal from 4 on is sent once
more with the same goal id after its result (the server must answer it with the first decision and
not run it again). Every failure is the exception the library raised (type and message); a deadline
of ours that passed with neither an answer nor an error is a ``hang`` (a defect: the library has
deadlines of its own for acceptance and cancel), and so is a result not received within our deadline
although the goal had ended and its get_result had time to be re-asked twice.

Prints one JSON row per level and a markdown table. The same file is both sides of a run:
``... actions_lossy serve SESSION`` / ``... actions_lossy send SESSION N ACCEPT_S RESULT_S``
(starts after a line on stdin), SESSION being ``multicast:IFACE`` as in commands.py.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from collections import Counter
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

from .commands import SESSION_WAIT_S, _session, _wait_transport
from .stall_runs import reap, wait_ready

ACTION = "example_interfaces/action/Fibonacci"
NAME = "exp/fibonacci"
FEEDBACKS = 4             # a fast goal's feedback messages ...
FEEDBACK_GAP_S = 0.05     # ... this far apart
FAST_ORDER = 10
SLOW_ORDER = 50           # a goal of at least this order is slow (cancel-able)
SLOW_S = 4.0              # a slow goal's run when nobody cancels it: longer than RESULT_POLL_S
RESULT_POLL_S = 3.0       # the client's result_poll_s: a get_result unanswered this long is asked again
CANCEL_EVERY = 5          # goals 2, 7, 12, ... are slow and canceled
CANCEL_AFTER_S = 0.3
RESEND_EVERY = 5          # goals 4, 9, 14, ... are resent with their goal id after their result
HANG_MARGIN_S = 3.0       # a library deadline is allowed this much beyond ours before it is a hang


def serve(spec: str) -> None:
    """Serve until stdin closes, then print {"runs": {goal id: executions}, ...} as JSON."""
    from zenoh_robot import Node
    from zenoh_robot.actions import CancelResponse, ServerGoalHandle, goal_id_text
    from zenoh_robot.ros2 import ros2_action_type
    fib = ros2_action_type(ACTION)
    runs: Counter[str] = Counter()
    ends: dict[str, str] = {}
    lock = threading.Lock()

    def execute(handle: ServerGoalHandle) -> Any:
        gid = goal_id_text(bytes(handle.goal_id.uuid))
        with lock:
            runs[gid] += 1
        seq = [0, 1]
        slow = handle.request.order >= SLOW_ORDER
        end = time.monotonic() + SLOW_S
        n = 0
        while (time.monotonic() < end) if slow else (n < FEEDBACKS):
            if handle.is_cancel_requested:
                handle.canceled()
                with lock:
                    ends[gid] = "canceled"
                return fib.Result(sequence=seq)
            time.sleep(FEEDBACK_GAP_S)
            seq.append((seq[-1] + seq[-2]) % 1_000_000)     # int32 fields: a slow goal runs long
            n += 1
            handle.publish_feedback(fib.Feedback(sequence=seq[-8:]))
        handle.succeed()
        with lock:
            ends[gid] = "succeeded"
        return fib.Result(sequence=seq[-8:])

    with Node("action_server", config=_session(spec)) as node:
        server = node.create_action_server(fib, NAME, execute, cancel_callback=lambda _h: CancelResponse.ACCEPT)
        spinner = threading.Thread(target=node.spin, daemon=True)
        spinner.start()
        print("READY", flush=True)
        sys.stdin.readline()
        with lock:
            out = {"runs": dict(runs), "ends": dict(ends), "executions": server.executions,
                   "duplicates": server.duplicates, "rejected": server.rejected,
                   "service_duplicates": {s.name.rsplit("/", 1)[-1]: s.duplicates for s in server._services}}
        print(json.dumps(out), flush=True)
        node.shutdown()


def _reason(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def send(spec: str, n: int, accept_s: float, result_s: float) -> None:
    """Send ``n`` goals one after the other; print one JSON summary."""
    from zenoh_robot import Node
    from zenoh_robot.actions import CancelReturn, GoalStatus
    from zenoh_robot.ros2 import ros2_action_type
    fib = ros2_action_type(ACTION)
    with Node("action_client", config=_session(spec)) as node:
        linked = _wait_transport(node, SESSION_WAIT_S)
        client = node.create_action_client(fib, NAME, goal_timeout=accept_s, result_poll_s=RESULT_POLL_S)
        threading.Thread(target=node.spin, daemon=True).start()    # feedback callbacks run on the executor
        print("LINKED", flush=True)
        sys.stdin.readline()         # START: the server is serving
        goals: list[dict[str, Any]] = []
        for i in range(n):
            kind = "slow" if i == 0 else "cancel" if i % CANCEL_EVERY == 2 else "fast"
            goals.append(_one_goal(client, fib, i, kind, accept_s, result_s, GoalStatus, CancelReturn))
        attempts = {part: c.attempts for part, c in
                    (("send_goal", client._send), ("cancel_goal", client._cancel), ("get_result", client._result))}
        print(json.dumps({"linked": linked, "goals": goals, "attempts": attempts,
                          "server_is_ready": client.server_is_ready()}), flush=True)


def _one_goal(client: Any, fib: Any, i: int, kind: str, accept_s: float, result_s: float,
              status_t: Any, cancel_t: Any) -> dict[str, Any]:
    import uuid
    goal_id = uuid.uuid4()
    feedback: list[int] = []
    row: dict[str, Any] = {"goal": i, "kind": kind, "goal_id": goal_id.hex, "accepted": False, "status": None,
                           "feedback": 0, "cancel": None, "failure": None, "stage": None, "hang": False,
                           "resend": None}
    order = SLOW_ORDER if kind != "fast" else FAST_ORDER
    t0 = time.monotonic()

    def fail(stage: str, reason: str, hang: bool = False) -> dict[str, Any]:
        row.update(failure=reason or "(empty reason)", stage=stage, hang=hang, time_s=round(time.monotonic() - t0, 3),
                   feedback=len(feedback))
        return row
    try:
        handle = client.send_goal_async(fib.Goal(order=order), feedback_callback=lambda _m: feedback.append(1),
                                        goal_uuid=goal_id).result(accept_s + HANG_MARGIN_S)
    except FutureTimeout:
        return fail("accept", f"hang: no acceptance and no error within {accept_s + HANG_MARGIN_S:g} s", True)
    except Exception as exc:
        return fail("accept", _reason(exc))
    if not handle.accepted:
        return fail("accept", "rejected by the server")
    row["accepted"] = True
    row["accept_s"] = round(time.monotonic() - t0, 3)
    if kind == "cancel":
        time.sleep(CANCEL_AFTER_S)
        try:
            answer = handle.cancel_goal_async().result(accept_s + HANG_MARGIN_S)
            row["cancel"] = ("ok" if answer.return_code == cancel_t.ERROR_NONE and answer.goals_canceling
                             else cancel_t(answer.return_code).name)
        except FutureTimeout:
            row["cancel"] = f"hang: no cancel answer and no error within {accept_s + HANG_MARGIN_S:g} s"
            row["hang"] = True
        except Exception as exc:
            row["cancel"] = _reason(exc)
    t1 = time.monotonic()
    try:
        response = handle.get_result_async().result(result_s)
    except FutureTimeout:
        # The result is re-asked while a server is there (rclpy's get_result has no deadline either): our
        # deadline, not the library's, and its message says so. A hang if the goal had ended long before
        # (a fast or canceled goal) and the library had time to re-ask it twice.
        ended = kind == "fast" or row["cancel"] == "ok"
        return fail("result", f"no result within {result_s:g} s (get_result still re-asking)",
                    hang=ended and result_s > 2 * RESULT_POLL_S)
    except Exception as exc:
        return fail("result", _reason(exc))
    row["result_s"] = round(time.monotonic() - t1, 3)
    row["status"] = status_t(response.status).name
    if kind != "fast":
        # The result went out after the last feedback: give the last feedback messages a moment to land.
        time.sleep(0.1)
    row["feedback"] = len(feedback)
    row["time_s"] = round(time.monotonic() - t0, 3)
    if i % RESEND_EVERY == 4:
        try:
            again = client.send_goal_async(fib.Goal(order=order), goal_uuid=goal_id).result(accept_s + HANG_MARGIN_S)
            same = (again.accepted, again.stamp.sec, again.stamp.nanosec) == (True, handle.stamp.sec,
                                                                             handle.stamp.nanosec)
            row["resend"] = "same answer" if same else f"different answer: accepted={again.accepted}"
        except FutureTimeout:
            row["resend"] = "hang"
            row["hang"] = True
        except Exception as exc:
            row["resend"] = _reason(exc)
    return row


def run_level(loss_pct: float, goals: int = 20, accept_timeout: float = 5.0, result_timeout: float = 10.0,
              loss_model: str = "uniform") -> dict[str, Any]:
    """One loss level on a fresh lossy link (the loss on from start-up): the row (see summarise)."""
    from drone_lab.experiment.netns import LossyLink
    me = [sys.executable, "-m", "drone_lab.experiment.actions_lossy"]
    with LossyLink(loss_pct=loss_pct, loss_model=loss_model) as link:
        spec = {side: f"multicast:{link.dev(side)}" for side in link.sides}
        server = subprocess.Popen(link.exec_in("drone") + me + ["serve", spec["drone"]],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        sender = subprocess.Popen(link.exec_in("gcs") + me + ["send", spec["gcs"], str(goals), str(accept_timeout),
                                                              str(result_timeout)],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert server.stdout is not None and server.stdin is not None
            if not wait_ready(server):
                raise RuntimeError("action server did not start")
            assert sender.stdin is not None and sender.stdout is not None
            if not wait_ready(sender, word="LINKED"):
                raise RuntimeError("action client did not start")
            t0_ns = time.time_ns()
            budget = SESSION_WAIT_S + goals * (2 * accept_timeout + result_timeout + 3 * HANG_MARGIN_S) + 30
            client_out, client_err = sender.communicate("START\n", timeout=budget)
            t1_ns = time.time_ns()
            server.stdin.write("\n")
            server.stdin.flush()
            served = next((json.loads(ln) for ln in iter(server.stdout.readline, "") if ln.startswith("{")), None)
            if served is None:
                raise RuntimeError("action server ended without its summary")
        finally:
            if server.stdin:
                server.stdin.close()
            reap(sender, server)
        applied = link.applied_loss(t0_ns, t1_ns)
    lines = [ln for ln in client_out.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"action client failed: {client_err[-2000:]}")
    row = summarise(loss_pct, json.loads(lines[-1]), served)
    row["applied_loss_pct"] = None if applied is None else round(applied, 2)
    row["loss_model"], row["accept_timeout_s"], row["result_timeout_s"] = loss_model, accept_timeout, result_timeout
    row["window_s"] = round((t1_ns - t0_ns) / 1e9, 1)
    return row


def summarise(loss_pct: float, client: dict[str, Any], served: dict[str, Any]) -> dict[str, Any]:
    goals = client["goals"]
    n = max(1, len(goals))
    runs: dict[str, int] = served["runs"]
    accepted = [g for g in goals if g["accepted"]]
    results = [g for g in goals if g["status"] is not None]
    cancels = [g for g in goals if g["kind"] == "cancel"]
    failures = [{"goal": g["goal"], "kind": g["kind"], "stage": g["stage"], "reason": g["failure"],
                 "hang": g["hang"], "executed": runs.get(g["goal_id"], 0)} for g in goals if g["failure"]]
    fast = [g for g in results if g["kind"] == "fast"]
    return {
        "loss_pct": loss_pct, "goals": len(goals), "linked": client["linked"],
        "accepted_pct": round(100 * len(accepted) / n, 1),
        "result_pct": round(100 * len(results) / n, 1),
        "statuses": dict(Counter(g["status"] for g in results)),
        "cancel_goals": len(cancels),
        "canceled_ok": sum(1 for g in cancels if g["status"] == "STATUS_CANCELED"),
        "cancels": [{"goal": g["goal"], "cancel": g["cancel"], "status": g["status"], "failure": g["failure"]}
                    for g in cancels],
        "failures": failures,
        "hangs": sum(1 for g in goals if g["hang"]),
        "double_executions": sum(1 for v in runs.values() if v > 1),
        "executions": served["executions"],
        "executed_not_accepted": sum(1 for g in goals if not g["accepted"] and runs.get(g["goal_id"])),
        "resends": [g["resend"] for g in goals if g["resend"] is not None],
        "feedback_per_fast_goal": round(sum(g["feedback"] for g in fast) / max(1, len(fast)), 2),
        "feedback_sent_per_fast_goal": FEEDBACKS,
        "accept_s_max": max((g.get("accept_s", 0.0) for g in accepted), default=None),
        "result_s_max": max((g.get("result_s", 0.0) for g in results), default=None),
        "attempts": client["attempts"],
        "attempts_per_goal": round(sum(client["attempts"].values()) / n, 1),
        "server_duplicates": served["duplicates"], "service_duplicates": served["service_duplicates"],
    }


def table(rows: list[dict[str, Any]]) -> str:
    head = ("| loss each way (applied) | goals | accepted | result received | canceled ok | failures | hangs "
            "| run twice | feedback per fast goal | requests per goal |\n" + "|---" * 10 + "|")
    body = [f"| {r['loss_pct']:g} % ({r['applied_loss_pct']} %) | {r['goals']} | {r['accepted_pct']:g} % "
            f"| {r['result_pct']:g} % | {r['canceled_ok']} / {r['cancel_goals']} | {len(r['failures'])} "
            f"| {r['hangs']} | {r['double_executions']} | {r['feedback_per_fast_goal']} / "
            f"{r['feedback_sent_per_fast_goal']} | {r['attempts_per_goal']} |" for r in rows]
    return "\n".join([head, *body])


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "serve":
        serve(argv[1])
        return 0
    if argv and argv[0] == "send":
        send(argv[1], int(argv[2]), float(argv[3]), float(argv[4]))
        return 0
    p = argparse.ArgumentParser(prog="python -m drone_lab.experiment.actions_lossy", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--loss", type=float, nargs="+", default=[50.0], help="loss %% each way, per level")
    p.add_argument("--goals", type=int, default=20)
    p.add_argument("--accept-timeout", type=float, default=5.0, help="each goal's acceptance (and cancel) deadline")
    p.add_argument("--result-timeout", type=float, default=10.0, help="each goal's result deadline")
    p.add_argument("--loss-model", default="uniform", choices=("uniform", "bursty"))
    p.add_argument("--jsonl", help="append one JSON object per level here")
    args = p.parse_args(argv)
    from drone_lab.experiment.netns import unavailable_reason
    reason = unavailable_reason()
    if reason:
        print(f"error: {reason}", file=sys.stderr)
        return 2
    rows = []
    for loss in args.loss:
        row = run_level(loss, args.goals, args.accept_timeout, args.result_timeout, args.loss_model)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(json.dumps(row) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
