"""``zenoh-robot stats [TOPIC]``: every subscription's topic statistics, as a live table.

Subscriptions with statistics enabled publish a ``TopicStatistics`` per window on
``<namespace>/statistics/<topic>`` (zenoh_robot.topic_statistics.default_statistics_key).
``drop`` counts samples the subscriber's own KEEP_LAST queue overwrote before its callback
ran (the application, or its executor, was slower than the stream); ``lost`` counts samples
that never arrived. Both are totals since the subscription started. ``cpu %`` is the
executor time the subscription took over the window in % of one core (``busy_pct``), then
``/budget`` when it has one (``TopicStatisticsOptions.cpu_budget_pct``), red when over.

This listens to ``**/statistics/**`` with a plain Zenoh subscriber (no graph entry, no QoS
matching: it hears every publisher of statistics), skipping and counting samples there that are not ``TopicStatistics``.
"""
from __future__ import annotations

import argparse
import math
import queue
import sys
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from zenoh_robot.message import type_support
from zenoh_robot.session_args import add_session_arguments

from .common import add_duration_arg, cli_node, deadline_of, quiet_exit
from .main import CliError

if TYPE_CHECKING:
    from rich.table import Table

    from zenoh_robot.msgs import TopicStatistics

STATS_KEY = "**/statistics/**"     # `**` also matches no chunk: "statistics/chatter" too
REFRESH_PERIOD = 0.25              # seconds between table redraws
MAX_PENDING_LINES = 10_000         # --plain: lines not yet printed (a stalled pipe must not grow us)
STALE_WINDOWS = 3                  # a row not updated for this many windows is dimmed
# lost and drop are counts since the subscription started (TopicStatistics.lost/.dropped), not per window.
LEGEND = ("lost: samples that never arrived (gaps in the publisher's sequence numbers); "
          "drop: samples the subscriber's KEEP_LAST queue overwrote before the callback ran: "
          "the application was slower than the stream (or the stream came in bursts longer than the depth); "
          "both counted since the subscription started; "
          "cpu %: executor time draining the subscription (decode, checks, callback) over the window, "
          "% of one core, /budget when set, red when over")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("stats", help="live table of topic statistics (age, period, rate, lost, cpu %%)")
    p.add_argument("topic", nargs="?", help="only statistics of this measured topic, e.g. /uav1/setpoint")
    add_session_arguments(p)
    add_duration_arg(p)
    p.add_argument("--plain", action="store_true",
                   help="print one line per statistics message instead of the live table "
                        "(the default when stdout is not a terminal)")
    p.set_defaults(func=run)


@dataclass(frozen=True)
class StatsRow:
    key: str                 # the statistics key it came on
    stats: "TopicStatistics"
    updated_wall: float      # time.time() of arrival
    updated_mono: float

    @property
    def topic(self) -> str:
        return self.stats.topic or "/" + self.key

    @property
    def window_s(self) -> float:
        return max((self.stats.window_stop - self.stats.window_start) / 1e9, 0.0)


def decode(data: bytes) -> "TopicStatistics | None":
    """The TopicStatistics in a sample, None for anything else on a statistics key."""
    from zenoh_robot.msgs import TopicStatistics
    from zenoh_robot.wire import ENVELOPE, MalformedSample

    try:
        env = ENVELOPE.unpack(data)
    except MalformedSample:
        return None
    if env.type_hash != type_support(TopicStatistics).hash:
        return None
    try:
        stats: TopicStatistics = type_support(TopicStatistics).decode(env.body)
    except (TypeError, ValueError):
        return None
    return stats


def _same_topic(a: str, b: str) -> bool:
    return a.strip("/") == b.strip("/")


class StatsBoard:
    """The latest statistics per statistics key and node: fed on Zenoh's thread, read on the main one."""

    def __init__(self, topic_filter: str | None, lines: bool = False) -> None:
        self.topic_filter = topic_filter
        self.skipped = 0
        self.lines_dropped = 0
        # Only --plain prints every update; the live table reads the latest rows, so a queue of
        # updates nobody drains would grow for as long as the command runs.
        self.updates: queue.Queue[StatsRow] | None = queue.Queue(MAX_PENDING_LINES) if lines else None
        self._lock = threading.Lock()
        self._rows: dict[tuple[str, str], StatsRow] = {}

    def on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        stats = decode(sample.payload.to_bytes())
        if stats is None:
            with self._lock:
                self.skipped += 1
            return
        row = StatsRow(key, stats, time.time(), time.monotonic())
        if self.topic_filter and not _same_topic(row.topic, self.topic_filter):
            return
        with self._lock:
            self._rows[(key, stats.node)] = row
        if self.updates is not None:
            try:
                self.updates.put_nowait(row)
            except queue.Full:
                with self._lock:
                    self.lines_dropped += 1

    def rows(self) -> list[StatsRow]:
        with self._lock:
            return sorted(self._rows.values(), key=lambda r: (r.topic, r.stats.node))


# -- formatting ------------------------------------------------------------------------------
def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None     # NaN: no sample in the window (ROS 2's rule)
    return float(value)


def _ms(value: Any) -> str:
    v = _number(value)
    return "-" if v is None else f"{v:.2f}"


def _rate(row: StatsRow) -> str:
    period = _number(row.stats.message_period_ms.average)
    return "-" if period is None or period <= 0 else f"{1000.0 / period:.1f}"


def _samples(row: StatsRow) -> int:
    s = row.stats
    counts = [s.message_age_ms.sample_count, s.message_period_ms.sample_count]
    return max((c for c in counts if isinstance(c, int)), default=0)


def _pct(value: Any) -> str:
    v = _number(value)
    return "-" if v is None else f"{v:.1f}"


def cpu_text(s: "TopicStatistics") -> str:
    """``3.1`` or, with a budget, ``3.1/5``; ``-`` when not measured."""
    budget = _number(s.budget_pct)
    return _pct(s.busy_pct) + ("" if budget is None else f"/{budget:g}")


def over_budget(s: "TopicStatistics") -> bool:
    busy, budget = _number(s.busy_pct), _number(s.budget_pct)
    return busy is not None and budget is not None and busy > budget


def plain_line(row: StatsRow) -> str:
    s = row.stats
    age = s.message_age_ms
    stamp = time.strftime("%H:%M:%S", time.localtime(row.updated_wall))
    over = f" OVER_BUDGET windows_over={s.over_budget_windows}" if over_budget(s) else ""
    return (f"{row.topic} node={s.node} age_ms avg={_ms(age.average)} min={_ms(age.minimum)} "
            f"max={_ms(age.maximum)} period_ms avg={_ms(s.message_period_ms.average)} rate_hz={_rate(row)} "
            f"samples={_samples(row)} lost={s.lost} dropped={s.dropped} cpu_pct={cpu_text(s)}{over} "
            f"updated={stamp} key={row.key}")


def render_table(board: StatsBoard) -> "Table":
    from rich import box
    from rich.table import Table
    from rich.text import Text

    table = Table(title=f"topic statistics on {STATS_KEY} (ms; n: samples in the window; last: s since update)",
                  title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    for name in ("topic", "node"):
        table.add_column(name, overflow="fold", min_width=8)
    for name in ("age avg/min/max", "period", "Hz", "n", "lost", "drop", "cpu %", "last"):
        table.add_column(name, justify="right", no_wrap=True)
    now = time.monotonic()
    for row in board.rows():
        s, age = row.stats, row.stats.message_age_ms
        since = now - row.updated_mono
        stale = row.window_s > 0 and since > STALE_WINDOWS * row.window_s
        cpu = Text(cpu_text(s), style="bold red" if over_budget(s) else "")
        table.add_row(row.topic, s.node, f"{_ms(age.average)}/{_ms(age.minimum)}/{_ms(age.maximum)}",
                      _ms(s.message_period_ms.average), _rate(row), str(_samples(row)), str(s.lost),
                      str(s.dropped), cpu, f"{since:.1f}", style="dim" if stale else None)
    if not table.rows:
        table.caption = "waiting for topic statistics (subscriptions publish them when statistics are enabled)"
    else:
        table.caption = LEGEND + (f"\n{board.skipped} sample(s) on statistics keys were not TopicStatistics"
                                  if board.skipped else "")
    table.caption_justify = "left"
    return table


# -- running ---------------------------------------------------------------------------------
def _remaining(deadline: float | None) -> float | None:
    return None if deadline is None else deadline - time.monotonic()


def _watch_plain(board: StatsBoard, deadline: float | None) -> None:
    assert board.updates is not None
    print(f"# {LEGEND}", flush=True)    # a comment line: the data lines all start with the topic
    while True:
        left = _remaining(deadline)
        if left is not None and left <= 0:
            return
        try:
            row = board.updates.get(timeout=0.2 if left is None else min(0.2, left))
        except queue.Empty:
            continue
        print(plain_line(row), flush=True)


def _watch_live(board: StatsBoard, deadline: float | None) -> None:
    from rich.live import Live

    with Live(render_table(board), auto_refresh=False, transient=False) as live:
        while True:
            left = _remaining(deadline)
            if left is not None and left <= 0:
                return
            time.sleep(REFRESH_PERIOD if left is None else min(REFRESH_PERIOD, left))
            live.update(render_table(board), refresh=True)


@quiet_exit
def run(args: argparse.Namespace) -> int:
    deadline = deadline_of(args)
    if args.topic is not None and not args.topic.strip("/"):
        raise CliError("TOPIC must be a topic name, e.g. /uav1/setpoint")
    plain = args.plain or not sys.stdout.isatty()
    board = StatsBoard(args.topic, lines=plain)
    with cli_node("stats", args) as node:
        zsub = node.session.declare_subscriber(STATS_KEY, board.on_sample)
        try:
            (_watch_plain if plain else _watch_live)(board, deadline)
        finally:
            try:
                zsub.undeclare()
            except Exception:
                pass
    if not board.rows():
        print("no topic statistics received" + (f" for {args.topic}" if args.topic else ""), file=sys.stderr)
    if board.lines_dropped:
        print(f"{board.lines_dropped} update(s) not printed: output could not keep up", file=sys.stderr)
    if board.skipped:
        print(f"skipped {board.skipped} sample(s) on statistics keys that are not TopicStatistics", file=sys.stderr)
    return 0
