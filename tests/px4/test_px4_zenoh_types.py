"""px4_zenoh's codecs and keys against what real PX4 SITL (zenoh module) said and heard.

Ground truth: ../shared/px4_zenoh_traces (as on CI: the clone's parent holds shared/): every used
/fmu/out topic's samples of the ground recording decode to the recorded fields (PX4's trailing bytes
cut), what the flight sent re-encodes byte for byte from its recorded fields, and the keys learnt
from PX4's own tokens are the keys the flight used. A hand-built PX4 token with a wrong hash, over a
real Zenoh session, is reported by name and that topic refused.
"""
from __future__ import annotations

import gzip
import json
import logging
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from px4_zenoh import Px4ZenohLink, topics
from px4_zenoh.session import Px4Endpoint, free_tcp_endpoint
from px4_zenoh.uorb import UorbCodec, load_types

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

TRACES = Path(__file__).resolve().parents[3] / "shared" / "px4_zenoh_traces"
USED_TYPES = sorted({t.type_short for t in topics.USED})


@pytest.fixture(scope="module")
def types() -> dict[str, Any]:
    return load_types(None, USED_TYPES)


def _rows(path: Path) -> Iterator[dict[str, Any]]:
    assert path.exists(), f"{path}: the PX4 Zenoh traces are missing (CI has them beside the clone)"
    with gzip.open(path, "rt") as f:
        for line in f:
            yield json.loads(line)


def _same(ours: Any, theirs: Any) -> bool:
    if isinstance(theirs, list):
        ours = list(ours)
        return len(ours) == len(theirs) and all(_same(a, b) for a, b in zip(ours, theirs, strict=True))
    if isinstance(theirs, str):   # "NaN", "Infinity", "-Infinity"
        return math.isnan(ours) if theirs == "NaN" else ours == float(theirs)
    if isinstance(theirs, float) or isinstance(ours, float):
        return ours == theirs or math.isclose(ours, theirs, rel_tol=1e-6)
    return bool(ours == theirs)


def test_every_used_topic_of_the_ground_trace_decodes_to_the_recorded_fields(types: dict[str, Any]) -> None:
    inbound = {t.name: UorbCodec.of(types[t.type_short]) for t in topics.USED if t.direction == topics.OUT}
    seen: dict[str, int] = dict.fromkeys(inbound, 0)
    trailing = 0
    for row in _rows(TRACES / "ground" / "ground.jsonl.gz"):
        codec = inbound.get(row.get("topic", ""))
        if codec is None or "decoded" not in row or seen[row["topic"]] >= 40:
            continue
        payload = bytes.fromhex(row["payload_hex"])
        assert codec.body_len == row["cdr_body_len"], row["topic"]
        trailing += len(payload) - 4 - codec.body_len
        msg = codec.decode(payload)
        for field, value in row["decoded"].items():
            assert _same(getattr(msg, field), value), f"{row['topic']}.{field}: {getattr(msg, field)} != {value}"
        seen[row["topic"]] += 1
    # vehicle_command_ack is sporadic: the ground trace has PX4's stray command-211 ACKs.
    assert all(n > 0 for n in seen.values()), {k: v for k, v in seen.items() if not v}
    assert trailing > 0, "PX4's trailing bytes were never exercised"


def test_what_we_send_is_byte_equal_to_the_flight_trace(types: dict[str, Any]) -> None:
    outbound = {t.name: UorbCodec.of(types[t.type_short]) for t in topics.USED if t.direction == topics.IN}
    seen: dict[str, int] = dict.fromkeys(outbound, 0)
    for row in _rows(TRACES / "flight" / "flight.jsonl.gz"):
        if row.get("dir") != "py->px4" or seen.get(row["topic"], 99) >= 50:
            continue
        codec = outbound[row["topic"]]
        fields = {k: (float(v) if isinstance(v, str) else [float(x) if isinstance(x, str) else x for x in v]
                      if isinstance(v, list) else v) for k, v in row["decoded"].items()}
        assert codec.encode(codec.msg_type(**fields)).hex() == row["payload_hex"], row["topic"]
        seen[row["topic"]] += 1
    assert all(n > 0 for n in seen.values()), seen


def test_the_keys_learnt_from_pxs_tokens_are_the_keys_the_flight_used(types: dict[str, Any]) -> None:
    codecs = [UorbCodec.of(types[s]) for s in USED_TYPES]
    book = topics.KeyBook(0, {c.type_name: c.type_hash for c in codecs})
    lines = [ln.strip() for ln in (TRACES / "tokens.txt").read_text().splitlines() if ln.startswith("@ros2_lv")]
    assert len(lines) == 47
    assert [book.learn(ln) for ln in lines] == [None] * 47
    assert book.mismatches() == [] and set(book.known()) == {t.name for t in topics.USED}
    flight_keys = {r["topic"]: r["key"] for r in _rows(TRACES / "flight" / "flight.jsonl.gz") if "key" in r}
    for name, key in book.known().items():
        assert flight_keys[name] == key, name


def test_a_px4_token_with_a_wrong_hash_is_reported_by_name(caplog: pytest.LogCaptureFixture) -> None:
    """A PX4 built from other px4_msgs announces vehicle_status with another hash: the backend says so
    (log, event, summary) and takes nothing on that topic, over real Zenoh sessions."""
    ep = free_tcp_endpoint()
    wrong = "RIHS01_" + "ab" * 32
    events: list[tuple[str, dict[str, Any]]] = []
    caplog.set_level(logging.WARNING, logger="px4_zenoh")
    with Px4ZenohLink(Px4Endpoint("router", ep), on_event=lambda n, d: events.append((n, d))) as link:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([ep]))
        with zenoh.open(conf) as px4:
            token = (f"@ros2_lv/0/{'1' * 32}/0/11/MP/%/%/px4_aabbcc00000000000000000000000000/"
                     f"%fmu%out%vehicle_status/px4_msgs::msg::dds_::VehicleStatus_/{wrong}/::,7:,:,:,,")
            tok = px4.liveliness().declare_token(token)
            deadline = time.monotonic() + 5
            while not link.hash_mismatches() and time.monotonic() < deadline:
                time.sleep(0.02)
            # PX4's samples on that key are refused, never half-decoded.
            pub = px4.declare_publisher(f"0/fmu/out/vehicle_status/px4_msgs::msg::dds_::VehicleStatus_/{wrong}")
            for _ in range(5):
                pub.put(b"\x00\x01\x00\x00" + bytes(120))
                time.sleep(0.02)
            time.sleep(0.2)
            tok.undeclare()
        mm = link.hash_mismatches()
        assert [m.topic for m in mm] == ["/fmu/out/vehicle_status"]
        assert mm[0].theirs == wrong and mm[0].ours.startswith("RIHS01_b98c7043")
        assert "/fmu/out/vehicle_status" in str(mm[0]) and "--px4-msgs" in str(mm[0])
        summary = link.backend_summary()
        assert summary["stats"]["hash_mismatches"] == 1 and summary["stats"]["wrong_key_samples"] == 5
        assert summary["stats"]["samples_decoded"] == 0 and not link.connected
        assert "/fmu/out/vehicle_status" not in summary["keys_learnt"]
        assert [d["topic"] for n, d in events if n == "hash_mismatch"] == ["/fmu/out/vehicle_status"]
    assert any("/fmu/out/vehicle_status" in r.getMessage() and wrong in r.getMessage() for r in caplog.records)


def test_every_bundled_definition_hashes_and_sizes_as_px4_announced() -> None:
    """The bundled px4_msgs (field layouts only) are PX4's: each topic type's RIHS01 hash equals the one
    PX4 put in its keys and its CDR body is as long as PX4's, for all 46 topics PX4 declared."""
    from zenoh_robot.ros2.types import rihs01

    declared = json.loads((TRACES / "topics.json").read_text())["topics"]
    bundled = load_types()
    assert len(declared) == 46
    for row in declared:
        short = row["type"].rsplit("/", 1)[1]
        assert short in bundled, f"{short} ({row['topic']}) is not bundled"
        assert rihs01(row["type"]) == row["rihs01"], row["topic"]
        assert UorbCodec.of(bundled[short]).body_len == row["cdr_body_len"], row["topic"]
