"""Record the TopicStatistics messages of a system to CSV or JSON (a tool, not the library).

``StatisticsRecorder.subscribe(node, topic)`` listens on statistics topics published by the
collectors of ``zenoh_robot.topic_statistics``; ``save_csv`` / ``save_json`` write atomically,
``load_csv`` / ``load_json`` read a file back with its column types.
"""
from __future__ import annotations

import csv
import json
import math
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zenoh_robot.msgs import TopicStatistics
from zenoh_robot.qos import QoSProfile, ReliabilityPolicy

if TYPE_CHECKING:
    from zenoh_robot.node import Node
    from zenoh_robot.subscription import Subscription

# A recorder may listen to many collectors whose windows end together: a deeper queue.
RECORDER_QOS = QoSProfile(ReliabilityPolicy.RELIABLE, depth=100)

# -- recording -----------------------------------------------------------------------
COLUMNS: tuple[str, ...] = (
    "topic", "node", "window_start", "window_stop",
    "age_avg_ms", "age_min_ms", "age_max_ms", "age_std_ms", "age_count",
    "period_avg_ms", "period_min_ms", "period_max_ms", "period_std_ms", "period_count",
    "received", "lost", "dropped",
)
_STR_COLUMNS = frozenset({"topic", "node"})
_INT_COLUMNS = frozenset({"window_start", "window_stop", "age_count", "period_count", "received", "lost",
                          "dropped"})


def _flatten(msg: TopicStatistics) -> dict[str, Any]:
    row: dict[str, Any] = {"topic": msg.topic, "node": msg.node, "window_start": msg.window_start,
                           "window_stop": msg.window_stop}
    for prefix, e in (("age", msg.message_age_ms), ("period", msg.message_period_ms)):
        row[f"{prefix}_avg_ms"] = float(e.average)
        row[f"{prefix}_min_ms"] = float(e.minimum)
        row[f"{prefix}_max_ms"] = float(e.maximum)
        row[f"{prefix}_std_ms"] = float(e.std_dev)
        row[f"{prefix}_count"] = e.sample_count
    row.update(received=msg.received, lost=msg.lost, dropped=msg.dropped)
    return row


def _typed(row: dict[str, Any], where: str) -> dict[str, Any]:
    """A row read back from CSV/JSON with its column types (None/"nan" -> NaN)."""
    if not isinstance(row, dict):
        raise ValueError(f"{where}: a row must be an object, got {row!r}")
    missing = [c for c in COLUMNS if c not in row]
    if missing:
        raise ValueError(f"{where}: not a topic statistics file, missing column(s) {missing}")
    out: dict[str, Any] = {}
    for c in COLUMNS:
        v = row[c]
        try:
            if c in _STR_COLUMNS:
                out[c] = "" if v is None else str(v)
            elif c in _INT_COLUMNS:
                out[c] = int(v)
            else:
                out[c] = math.nan if v is None or v == "" else float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: column {c!r} has a bad value {v!r}") from None
    return out


def _prepare(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if p.is_dir():
        raise IsADirectoryError(f"cannot write statistics to {str(p)!r}: it is a directory")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"cannot create the directory for {str(p)!r}: {exc}") from exc
    return p


def _write_atomically(p: Path, write: Callable[[Any], None], newline: str | None = None) -> None:
    # A crash mid-write must not leave a truncated file where a good one was.
    tmp = p.with_name(p.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8", newline=newline) as f:
            write(f)
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OSError(f"cannot write statistics to {str(p)!r}: {exc}") from exc


class StatisticsRecorder:
    """Collects ``TopicStatistics`` messages as flat rows and saves them as CSV or JSON.

    ``record`` works as a subscription callback (see ``subscribe``) or a collector
    listener, from any thread. At most ``max_rows`` rows are kept: later ones are
    counted in ``dropped_rows`` and not stored, so a saved file is always a contiguous
    run from the start of the recording.
    """

    def __init__(self, max_rows: int = 100_000) -> None:
        if isinstance(max_rows, bool) or not isinstance(max_rows, int) or max_rows < 1:
            raise ValueError(f"StatisticsRecorder: max_rows must be an integer >= 1, got {max_rows!r}")
        self.max_rows = max_rows
        self.dropped_rows = 0
        self.subscription: "Subscription[TopicStatistics] | None" = None
        self._node: "Node | None" = None
        self._rows: list[dict[str, Any]] = []
        self._lock = threading.Lock()

    @classmethod
    def subscribe(cls, node: "Node", topic: str, qos: QoSProfile | int = RECORDER_QOS, *,
                  max_rows: int = 100_000) -> "StatisticsRecorder":
        """A recorder fed by a subscription on the statistics ``topic`` (node name rules:
        relative names are namespaced, ``/name`` is absolute). Runs on ``node``'s executor."""
        rec = cls(max_rows)
        rec.subscription = node.create_subscription(TopicStatistics, topic, rec.record, qos)
        rec._node = node
        return rec

    def record(self, msg: TopicStatistics) -> None:
        if not isinstance(msg, TopicStatistics):
            raise TypeError(f"StatisticsRecorder.record takes a TopicStatistics, got {type(msg).__name__}")
        row = _flatten(msg)
        with self._lock:
            if len(self._rows) >= self.max_rows:
                self.dropped_rows += 1
                return
            self._rows.append(row)

    __call__ = record

    @property
    def rows(self) -> list[dict[str, Any]]:
        """A copy of the recorded rows (columns as ``COLUMNS``)."""
        with self._lock:
            return [dict(r) for r in self._rows]

    def __len__(self) -> int:
        with self._lock:
            return len(self._rows)

    def clear(self) -> None:
        with self._lock:
            self._rows.clear()
            self.dropped_rows = 0

    def save_csv(self, path: str | os.PathLike[str]) -> Path:
        """One row per window, header = ``COLUMNS``; NaN is written ``nan``. Creates parent dirs."""
        p = _prepare(path)
        rows = self.rows

        def write(f: Any) -> None:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            w.writerows(rows)      # csv writes float NaN as "nan", which float() reads back
        _write_atomically(p, write, newline="")
        return p

    def save_json(self, path: str | os.PathLike[str]) -> Path:
        """``{"columns": [...], "rows": [{...}], "dropped_rows": n}``; NaN is written null
        (NaN is not JSON, and strict parsers refuse it). Creates parent dirs."""
        p = _prepare(path)
        with self._lock:
            rows = [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()}
                    for r in self._rows]
            doc = {"columns": list(COLUMNS), "rows": rows, "dropped_rows": self.dropped_rows}
        _write_atomically(p, lambda f: json.dump(doc, f, indent=1, allow_nan=False))
        return p

    @staticmethod
    def load_csv(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
        """Rows written by ``save_csv``, typed as recorded ("nan" -> NaN)."""
        p = Path(path)
        try:
            with open(p, encoding="utf-8", newline="") as f:
                return [_typed(r, str(p)) for r in csv.DictReader(f)]
        except OSError as exc:
            raise OSError(f"cannot read statistics from {str(p)!r}: {exc}") from exc

    @staticmethod
    def load_json(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
        """Rows written by ``save_json``, typed as recorded (null -> NaN)."""
        p = Path(path)
        try:
            with open(p, encoding="utf-8") as f:
                doc = json.load(f)
        except OSError as exc:
            raise OSError(f"cannot read statistics from {str(p)!r}: {exc}") from exc
        except json.JSONDecodeError as exc:
            raise ValueError(f"{str(p)!r} is not JSON: {exc}") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("rows"), list):
            raise ValueError(f"{str(p)!r}: not a topic statistics file (no 'rows' list)")
        return [_typed(r, str(p)) for r in doc["rows"]]

    def close(self) -> None:
        """Destroy the subscription made by ``subscribe`` (the rows stay)."""
        sub, node = self.subscription, self._node
        self.subscription = None
        if sub is not None and node is not None:
            node.destroy_subscription(sub)


__all__ = ["StatisticsRecorder", "COLUMNS"]
