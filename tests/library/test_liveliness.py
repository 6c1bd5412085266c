"""Liveliness tokens and watches (zenoh_robot.liveliness) over real sessions."""
from __future__ import annotations

import threading

import pytest
from conftest import linked_configs, spinning_nodes, wait_for

from zenoh_robot import Node
from zenoh_robot.liveliness import LivelinessWatch

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def test_a_watch_sees_a_token_come_and_go_on_the_watchers_executor(ns: str) -> None:
    with spinning_nodes(ns) as (a, b):
        seen: list[tuple[str, bool, str]] = []
        b.watch_liveliness(f"{ns}/alive/*", lambda key, alive: seen.append(
            (key, alive, threading.current_thread().name)))
        token = a.declare_liveliness_token(f"{ns}/alive/gcs1")
        assert wait_for(lambda: (f"{ns}/alive/gcs1", True) in [s[:2] for s in seen])
        token.undeclare()
        token.undeclare()    # idempotent
        assert wait_for(lambda: (f"{ns}/alive/gcs1", False) in [s[:2] for s in seen])
        # Zenoh's threads only hand work over: every callback ran on the node's executor (spin thread).
        assert all(name.endswith("(spin)") for *_, name in seen), seen


def test_history_reports_tokens_alive_before_the_watch(ns: str) -> None:
    with spinning_nodes(ns) as (a, b):
        token = a.declare_liveliness_token(f"{ns}/alive/early")   # kept: a dropped handle undeclares
        probe: list[str] = []
        b.watch_liveliness(f"{ns}/alive/*", lambda key, alive: probe.append(key) if alive else None)
        assert wait_for(lambda: f"{ns}/alive/early" in probe)
        token.undeclare()


def test_a_token_goes_when_its_node_closes(ns: str) -> None:
    listen, connect = linked_configs()
    with Node("watcher", namespace=ns, config=listen) as b:
        spin = threading.Thread(target=b.spin, daemon=True)
        spin.start()
        state: dict[str, bool] = {}
        b.watch_liveliness(f"{ns}/alive/**", lambda key, alive: state.__setitem__(key, alive))
        with Node("holder", namespace=ns, config=connect) as a:
            token = a.declare_liveliness_token(f"{ns}/alive/holder")
            assert wait_for(lambda: state.get(f"{ns}/alive/holder") is True, 10.0) and token.key
        assert wait_for(lambda: state.get(f"{ns}/alive/holder") is False, 10.0)
    spin.join(timeout=2.0)


def test_a_failing_callback_does_not_stop_the_watch(ns: str) -> None:
    with spinning_nodes(ns) as (a, b):
        keys: list[str] = []

        def callback(key: str, alive: bool) -> None:
            keys.append(key)
            raise RuntimeError("boom")

        b.watch_liveliness(f"{ns}/alive/*", callback)
        tokens = [a.declare_liveliness_token(f"{ns}/alive/t{i}") for i in range(3)]
        assert wait_for(lambda: len(set(keys)) == 3)
        for t in tokens:
            t.undeclare()


def test_pending_changes_are_bounded_and_merged_per_key() -> None:
    """Without an executor draining, changes pile up in the table: bounded, latest state per key."""
    class Held:
        def __init__(self) -> None:
            self.work: list[object] = []

        def submit(self, work: object) -> None:
            self.work.append(work)

    class Sample:
        def __init__(self, key: str, put: bool) -> None:
            import zenoh
            self.key_expr = key
            self.kind = zenoh.SampleKind.PUT if put else zenoh.SampleKind.DELETE

    import zenoh

    from zenoh_robot.session_config import SessionConfig
    session = zenoh.open(SessionConfig(listen=[], multicast_scouting=False).to_zenoh())
    try:
        delivered: list[tuple[str, bool]] = []
        held = Held()
        watch = LivelinessWatch(session, "nobody/**", lambda k, a: delivered.append((k, a)), held)
        watch.MAX_PENDING = 4
        watch._on_sample(Sample("k/0", True))
        watch._on_sample(Sample("k/0", False))      # merged into k/0's latest state
        for i in range(1, 6):
            watch._on_sample(Sample(f"k/{i}", True))
        assert len(held.work) == 1                  # one drain handed over, however many changes
        assert watch.dropped == 2                   # k/4 and k/5 found no room
        held.work[0]()                              # type: ignore[operator]
        assert delivered == [("k/0", False), ("k/1", True), ("k/2", True), ("k/3", True)]
        watch.undeclare()
        watch._on_sample(Sample("k/9", True))       # after undeclare: ignored
        assert len(held.work) == 1
    finally:
        session.close()
