"""Commands over the resilient multicast session at 50 % loss each way: answered, and executed once.

Two network namespaces joined by a veth (netns.LossyLink, root), a server process and a client
process (zenoh_robot/tools/experiment/commands.py): 30 calls with a 2 s deadline. Without the
client's retries one attempt is answered with p = 0.25 (request and reply each cross a 50 % link),
so the >= 90 % bound fails; without the server's idempotency cache the retries execute twice.
"""
from __future__ import annotations

import pytest
from conftest import skip_unless_required


@pytest.mark.netns
def test_commands_answered_and_executed_once_at_50_percent_loss() -> None:
    from zenoh_robot.tools.experiment.commands import run_level
    from zenoh_robot.tools.experiment.netns import unavailable_reason

    reason = unavailable_reason()
    if reason:
        skip_unless_required(f"lossy command test: network namespaces are unavailable: {reason}")
    row = run_level(50.0, calls=30, timeout=2.0)
    assert row["linked"], "the multicast session never formed"
    assert row["success_rate"] >= 0.9, row
    assert row["double_executions"] == 0, row
    assert row["attempts_per_call"] > 1.0, row      # the loss was real and the retries did the work
