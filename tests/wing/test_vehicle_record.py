"""``companion --vehicle-record FILE``: the vehicle side sampled every 20 ms, capped on disk
(``--vehicle-record-max-mb``): past the cap FILE becomes FILE.1 and a new FILE starts (issue #38: a
companion that runs for days fills no disk)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import cli

CAP = 4000     # bytes: ~20 lines of ~200 B, filled in under a second at 50 lines/s


@pytest.mark.usefixtures("own_domain")
def test_the_vehicle_record_rotates_at_its_cap_and_every_line_is_json(tmp_path: Path) -> None:
    record = tmp_path / "vehicle.jsonl"
    run = cli("companion", "--id", "uavrec", "--px4", "sim", "--camera", "none", "--duration", "4",
              "--listen", "tcp/127.0.0.1:0", "--vehicle-record", str(record),
              "--vehicle-record-max-mb", str(CAP / 1e6), timeout=90)
    assert run.returncode == 0, run.stderr[-2000:]
    older = record.with_name(record.name + ".1")
    assert older.exists() and record.exists(), sorted(p.name for p in tmp_path.iterdir())
    longest = max(len(ln) + 1 for p in (record, older) for ln in p.read_text().splitlines())
    assert CAP <= older.stat().st_size < CAP + longest            # cut at the first line past the cap
    assert record.stat().st_size < CAP + longest
    for p in (record, older):
        rows = [json.loads(ln) for ln in p.read_text().splitlines()]
        assert rows and all({"t", "mode", "armed", "pos"} <= set(r) for r in rows)
