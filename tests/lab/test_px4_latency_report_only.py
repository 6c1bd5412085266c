"""`zenoh-robot lab px4-latency --report-only`, docs/cli.md's example, rewrites the table and leaves the
records it read alone (issue #39: run as written, it changed a tracked file: the records' gzip header time)."""
from __future__ import annotations

import math
import os
from pathlib import Path

from cli_helpers import cli

from drone_lab.px4_latency import Rep, Sample, write_results


def test_report_only_rewrites_the_table_not_the_records(tmp_path: Path) -> None:
    samples = [Sample("mavlink", 0, k, 10**18 + k, 100.0 + k / 20, 100.001 + k / 20, 100.001 + k / 20)
               for k in range(20)]
    write_results([Rep("mavlink", 0, samples, (0.5, math.nan, math.nan), (0.5, math.nan, math.nan))],
                  tmp_path, 20.0, 1.0)
    records = tmp_path / "latency.jsonl.gz"
    before = records.read_bytes()
    os.utime(records, (1, 1))
    (tmp_path / "latency.md").write_text("stale\n")
    r = cli("lab", "px4-latency", "--report-only", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert records.read_bytes() == before and records.stat().st_mtime == 1
    assert "| mavlink | 1 |" in (tmp_path / "latency.md").read_text()
