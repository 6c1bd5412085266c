"""The replay attack of issue #37, flown by real processes in two network namespaces with the nftables
loss rule (``drone_lab.experiment.replay_attack``): a plain zenoh session records a sealed mission off
the link; the recording is replayed into the running companion, into the companion restarted, and the
second (restarted) GCS's flight into that companion. The vehicle's mode, arming and position never
change, every replay is refused and counted by reason, and the legitimate GCS then flies a mission.

One cell here (two missions, ~1.5 min): multicast at 50 %, the resilient profile's radio link, where
the replay must be refused although the link drops half of it and half of the legitimate traffic. The
router cells (where the replay arrives whole) and the runs per cell are the sweep's, `python -m
drone_lab.experiment.replay_attack` (docs/security.md). Root only; under CI a missing capability fails."""
from __future__ import annotations

from pathlib import Path

import pytest
from conftest import skip_unless_required

from drone_lab.experiment.netns import unavailable_reason
from drone_lab.experiment.replay_attack import REPLAYS, ReplayCell, run_replay_cell
from drone_lab.experiment.secure_sweep import make_cell_link_keys

pytestmark = pytest.mark.netns


@pytest.mark.parametrize("cell", [ReplayCell(50.0, "multicast")], ids=lambda c: c.label)
def test_a_recorded_flight_replayed_after_a_restart_moves_nothing(cell: ReplayCell, tmp_path: Path) -> None:
    reason = unavailable_reason()
    if reason:
        skip_unless_required(reason)
    keys = make_cell_link_keys(tmp_path / "keys")
    r = run_replay_cell(cell, tmp_path / cell.label, keys, log=lambda *_: None)
    assert "error" not in r, r["error"]
    assert r["mission1"]["ok"], f"the recorded mission did not fly (see {tmp_path / cell.label}/gcs1.log)"
    for replay in REPLAYS:
        effect = r[replay]
        assert effect["samples"] > 0, (replay, effect)
        assert effect["untouched"], (replay, effect)
    # Refused, and counted by reason: replays into the running companion, captures from before its restart.
    first, second = r["companion1_refused"], r["companion2_refused"]
    assert first is not None and second is not None, "a companion wrote no summary"
    assert first["replayed"] > 0, first
    assert second["restarted"] > 0, second
    assert first["bad_tag"] == second["bad_tag"] == 0 and first["malformed"] == second["malformed"] == 0
    # ... and the legitimate GCS still flies the restarted companion.
    assert r["mission2"]["ok"], f"the mission after the replays failed (see {tmp_path / cell.label}/gcs2.log)"
