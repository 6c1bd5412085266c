"""Read a flight log back: its topics, types, counts and rates (``zenoh-robot bag info``).

A finished file is read through its summary (index, statistics); a file cut short
(recorder killed, disk full, copied mid-flight) has no summary, so it is read as a
stream up to its last complete record: every finished chunk is still there.
"""
from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from . import schemas


@dataclass(slots=True)
class Record:
    """One message with its channel and schema (schema None for schemaless raw channels)."""
    schema: Schema | None
    channel: Channel
    message: Message


@dataclass
class TopicSummary:
    topic: str
    type_name: str
    encoding: str
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    metadata: dict[str, str] = field(default_factory=dict)

    @property
    def rate_hz(self) -> float:
        span = (self.last_ns - self.first_ns) / 1e9
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0


@dataclass
class BagInfo:
    path: Path
    size: int
    complete: bool                  # False: no summary (cut short); read up to the last record
    messages: int = 0
    start_ns: int = 0
    end_ns: int = 0
    topics: dict[tuple[str, str], TopicSummary] = field(default_factory=dict)
    recording: dict[str, str] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.messages else 0.0


MCAP_MAGIC = b"\x89MCAP0\r\n"


class NotMcapError(ValueError):
    """A file that cannot be read as MCAP at all, not even as a recording cut short (one line: why)."""


def check_mcap(path: str | Path) -> None:
    """Raise NotMcapError unless ``path`` begins as an MCAP file does (its magic, then a Header record).

    iter_records stops quietly where a file stops making sense, which is right for a recording cut
    short, but would show a text file, an empty file or a missing one as an empty recording."""
    p = Path(path)
    if not p.exists():
        raise NotMcapError(f"{p}: no such file")
    if p.is_dir():
        raise NotMcapError(f"{p} is a directory, not an MCAP file")
    with open(p, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
        if not head:
            raise NotMcapError(f"{p} is empty: not an MCAP file")
        if head != MCAP_MAGIC:
            if MCAP_MAGIC.startswith(head):
                raise NotMcapError(f"{p} is cut short inside MCAP's magic bytes: nothing to read")
            raise NotMcapError(f"{p} is not an MCAP file (it does not begin with MCAP's magic bytes)")
        f.seek(0)
        try:
            first = next(StreamReader(f, skip_magic=False, emit_chunks=False).records, None)
        except Exception:   # the mcap package raises several kinds for bytes that are not a record
            first = None
    if not isinstance(first, Header):
        raise NotMcapError(f"{p} is cut short before its first MCAP record (its header): nothing to read")


def iter_records(path: str | Path) -> Iterator[Record | Metadata]:
    """Every message (and metadata record) in file order; stops quietly where a cut file ends."""
    schemas_by_id: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with open(path, "rb") as f:
        reader = StreamReader(f, skip_magic=False, emit_chunks=False)
        records = reader.records
        while True:
            try:
                rec = next(records)
            except StopIteration:
                return
            except (McapError, EOFError, ValueError, OSError, Exception):   # cut mid-record
                return
            if isinstance(rec, Schema):
                schemas_by_id[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is not None:
                    yield Record(schemas_by_id.get(ch.schema_id), ch, rec)
            elif isinstance(rec, Metadata):
                yield rec
            elif isinstance(rec, Chunk):   # emit_chunks=False decodes them; kept for clarity
                continue


def has_summary(path: str | Path) -> bool:
    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:
        return False


def read_info(path: str | Path) -> BagInfo:
    """The recording's summary; NotMcapError for a file that is not one (check_mcap)."""
    p = Path(path)
    check_mcap(p)
    info = BagInfo(p, p.stat().st_size, has_summary(p))
    for item in iter_records(p):
        if isinstance(item, Metadata):
            if item.name == "zenoh_robot.recording":
                info.recording = dict(item.metadata)
            continue
        ch, msg = item.channel, item.message
        type_name = ch.metadata.get("zr.type") or (item.schema.name if item.schema else "")
        key = (ch.topic, ch.message_encoding)
        t = info.topics.get(key)
        if t is None:
            t = info.topics[key] = TopicSummary(ch.topic, type_name, ch.message_encoding, first_ns=msg.log_time,
                                                metadata=dict(ch.metadata))
        t.count += 1
        t.first_ns = min(t.first_ns, msg.log_time)
        t.last_ns = max(t.last_ns, msg.log_time)
        info.messages += 1
        info.start_ns = msg.log_time if info.messages == 1 else min(info.start_ns, msg.log_time)
        info.end_ns = max(info.end_ns, msg.log_time)
    return info


def format_info(info: BagInfo, show_raw: bool = False) -> str:
    from datetime import datetime

    def when(ns: int) -> str:
        return datetime.fromtimestamp(ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")

    lines = [f"Files:          {info.path}",
             f"Bag size:       {info.size / 1e6:.2f} MB" + ("" if info.complete else
                                                           "  (cut short: no summary, read to the last chunk)"),
             "Storage id:     mcap",
             f"Duration:       {info.duration_s:.3f} s"]
    if info.messages:
        lines += [f"Start:          {when(info.start_ns)}", f"End:            {when(info.end_ns)}"]
    lines.append(f"Messages:       {info.messages}")
    shown = [t for t in info.topics.values() if show_raw or not t.topic.startswith(schemas.RAW_PREFIX)]
    width = max((len(t.topic) for t in shown), default=10)
    lines.append("Topic information:")
    for t in sorted(shown, key=lambda t: t.topic):
        lines.append(f"  {t.topic:<{width}}  {t.type_name:<28} {t.count:>8} msgs  {t.rate_hz:8.2f} Hz  "
                     f"{t.encoding}")
    raw = sum(t.count for t in info.topics.values() if t.topic.startswith(schemas.RAW_PREFIX))
    if raw and not show_raw:
        lines.append(f"  (+ {raw} raw wire samples for replay; --raw lists them)")
    if info.recording:
        rec = {k: v for k, v in info.recording.items() if k != "topics"}
        lines.append("Recorder:       " + ", ".join(f"{k}={v}" for k, v in rec.items()))
    return "\n".join(lines)


def info_dict(info: BagInfo) -> dict[str, Any]:
    return {"path": str(info.path), "size": info.size, "complete": info.complete, "messages": info.messages,
            "duration_s": info.duration_s,
            "topics": [{"topic": t.topic, "type": t.type_name, "encoding": t.encoding, "count": t.count,
                        "rate_hz": t.rate_hz} for t in info.topics.values()],
            "recording": info.recording}


def dumps(info: BagInfo) -> str:
    return json.dumps(info_dict(info), indent=2, allow_nan=False)
