"""The GCS <-> drone contract is wired on both sides: every stream of ``drone_contract.streams.STREAM_SPECS``
has its publisher on the side the table names and a subscription on the other, with the table's type,
as a real companion and a real GCS announce them on the graph; and every command of the contract is
one the companion answers (not "unknown command") and `gcs cmd` offers.

A stream added to the table and forgotten on either side fails here.
"""
from __future__ import annotations

import pytest
from conftest import python_proc, stop_process, wait_for
from rigs import OP, drone

from drone_contract.commands import CLI_COMMANDS, COMMAND_SPECS, COMMANDS, CommandName, resolve_cli_name
from drone_contract.messages import Command, CommandResult
from drone_contract.streams import DOWN, STREAM_SPECS, UP
from zenoh_robot import Node
from zenoh_robot.message import type_support

DRONE = "uavc"


# Its companion and GCS (node names `companion`, `gcs`) in a domain of their own (conftest's own_domain).
pytestmark = pytest.mark.usefixtures("own_domain")


def _endpoints(node: Node, topic: str) -> tuple[dict[str, str], dict[str, str]]:
    pubs = {i.node_name: i.topic_type for i in node.get_publishers_info_by_topic(topic)}
    subs = {i.node_name: i.topic_type for i in node.get_subscriptions_info_by_topic(topic)}
    return pubs, subs


def test_every_stream_of_the_contract_is_wired_on_both_sides() -> None:
    with drone(DRONE), Node("contract_probe") as probe:
        gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", DRONE)
        try:
            def wired() -> bool:
                for spec in STREAM_SPECS.values():
                    pubs, subs = _endpoints(probe, f"/{DRONE}/{spec.name}")
                    publisher, subscriber = ("companion", "gcs") if spec.direction == DOWN else ("gcs", "companion")
                    if publisher not in pubs or subscriber not in subs:
                        return False
                return True
            ok = wait_for(wired, timeout=30.0)
            seen = {s: _endpoints(probe, f"/{DRONE}/{s}") for s in STREAM_SPECS}
            assert ok, f"not wired on both sides: {seen}"
            for name, spec in STREAM_SPECS.items():
                pubs, subs = seen[name]
                assert spec.direction in (UP, DOWN)
                if spec.message is not None:     # the image's type follows the profile's image mode
                    expected = type_support(spec.message).name
                    assert set(pubs.values()) | set(subs.values()) == {expected}, (name, pubs, subs)
                else:
                    side = "companion" if spec.direction == DOWN else "gcs"
                    other = "gcs" if side == "companion" else "companion"
                    assert pubs[side] == subs[other], (name, pubs, subs)
        finally:
            out = stop_process(gcs)
            assert "Traceback" not in out, out


def test_the_companion_answers_every_command_of_the_contract() -> None:
    # Every name is known to the companion: a refusal names a reason, never "unknown command".
    with drone(DRONE), Node("contract_cmd") as node:
        client = node.create_client(f"/{DRONE}/command", Command, CommandResult)
        assert client.wait_for_service(20.0)
        unknown = client.call(Command("no_such_command", 0.0, "", False, OP), timeout=10.0)
        assert not unknown.success and "unknown command" in unknown.message
        for name in (CommandName.RELEASE_CONTROL, CommandName.HOLD, CommandName.SET_PARAM):
            res = client.call(Command(str(name), 0.0, "NOT_ALLOWED", False, OP), timeout=10.0)
            assert "unknown command" not in res.message, (name, res)


def test_the_command_table_is_the_one_list() -> None:
    assert set(COMMANDS) == {str(n) for n in CommandName} == {str(n) for n in COMMAND_SPECS}
    assert set(CLI_COMMANDS) - set(COMMANDS) == {"offboard"}
    assert resolve_cli_name("offboard") is CommandName.OFFBOARD_START
    assert all(resolve_cli_name(c) in COMMAND_SPECS for c in CLI_COMMANDS)
