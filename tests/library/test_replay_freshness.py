"""Freshness across restarts (issue #37): every sealed sample names the start of its scope's owner
(the drone) and the owner's clock; the owner refuses what was sealed for an earlier start of it
(``restarted``), by a sender that never heard it (``unbound``) or longer ago than the bound
(``expired``), and a non-owner never lets a replay pull its estimate of the owner's clock back.
The seal is exercised as the wire carries it: sealed bytes from one format opened by another."""
from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import free_port, settled, wait_for

from drone_contract.messages import Command, CommandResult, DroneSetpoint, VehicleState
from zenoh_robot import Node, SessionConfig, envelope
from zenoh_robot.keyring import Keyring
from zenoh_robot.message import type_support
from zenoh_robot.tools import keys
from zenoh_robot.wire import ENVELOPE, sealed
from zenoh_robot.wire.freshness import FUTURE_S, OwnClock, ScopeClocks, age_ms, own_clock
from zenoh_robot.wire.sealed import STAMP, STAMP_AT, StaleSample, service_seal


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fleet")
    keys.make_link_keys(d, gcs={"gcs1": ["uav1"]})
    return d / keys.LINK_DIR


def _setpoint(x: float = 1.0) -> bytes:
    ts = type_support(DroneSetpoint)
    return envelope.pack(ts.name, ts.hash, 7, 1, time.time_ns(), ts.encode(DroneSetpoint(client_id="gcs1", x=x)))


def _state() -> bytes:
    ts = type_support(VehicleState)
    return envelope.pack(ts.name, ts.hash, 8, 1, time.time_ns(), ts.encode(VehicleState(mode="HOLD")))


def _drone(fleet: Path, boot_path: Path, fresh_s: float = 5.0) -> Any:
    return sealed(ENVELOPE, Keyring(fleet, "uav1"), boot_path=boot_path, fresh_s=fresh_s)


def _hear(gcs: Any, drone: Any) -> None:
    """``gcs`` opens one state sealed by ``drone``: what teaches a GCS the drone's start and clock."""
    gcs.keyed_decoder(type_support(VehicleState), "uav1/state")(drone.sealer("uav1/state")(_state()), None)


def _refusal(decode: Any, payload: bytes) -> str:
    with pytest.raises(StaleSample) as info:
        decode(payload, None)
    return info.value.reason


@pytest.mark.fast
def test_age_is_signed_and_survives_the_32_bit_wrap() -> None:
    assert age_ms(1000, 400) == 600 and age_ms(400, 1000) == -600
    assert age_ms(5, (1 << 32) - 5) == 10 and age_ms((1 << 32) - 5, 5) == -10


@pytest.mark.fast
def test_the_owner_checks_its_own_start_and_clock() -> None:
    clock = OwnClock(1_800_000_000)
    now = clock.now_ms()
    assert clock.check(clock.boot, now, 5.0) is None
    assert clock.check(0, now, 5.0) == "unbound"
    assert clock.check(clock.boot - 1, now, 5.0) == "restarted"
    assert clock.check(clock.boot + 1, now, 5.0) == "restarted"
    assert clock.check(clock.boot, (now - 6000) & 0xFFFFFFFF, 5.0) == "expired"
    assert clock.check(clock.boot, now + int(FUTURE_S * 1000) + 1000, 5.0) == "expired"


@pytest.mark.fast
def test_an_estimate_moves_only_forward_so_a_replay_cannot_pull_it_back() -> None:
    clocks = ScopeClocks()
    assert clocks.estimate("uav1") == (0, 0)
    assert clocks.check("uav1", 5, 100, 5.0) is None          # nothing known yet: nothing to compare
    clocks.learn("uav1", 5, 10_000)
    boot, ms = clocks.estimate("uav1")
    assert boot == 5 and 10_000 <= ms < 11_000
    clocks.learn("uav1", 5, 2_000)                             # an older sample of the same start: ignored
    clocks.learn("uav1", 4, 99_000)                            # an earlier start: ignored
    assert clocks.estimate("uav1")[0] == 5 and clocks.estimate("uav1")[1] >= 10_000
    assert clocks.check("uav1", 4, 99_000, 5.0) == "restarted"
    assert clocks.check("uav1", 5, 4_000, 5.0) == "expired"
    assert clocks.check("uav1", 5, 9_000, 5.0) is None
    clocks.learn("uav1", 6, 50)                                # the owner restarted: its new start wins
    assert clocks.estimate("uav1")[0] == 6 and clocks.known() == {"uav1": 6}


def test_a_start_counter_goes_up_across_processes_and_is_stored(tmp_path: Path) -> None:
    path = tmp_path / "uav1.boot"
    code = "import sys; from pathlib import Path; from zenoh_robot.wire.freshness import own_clock; " \
           "print(own_clock(Path(sys.argv[1])).boot)"
    boots = [int(subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True,
                                check=True, timeout=60).stdout) for _ in range(2)]
    assert boots[1] == boots[0] + 1 >= int(time.time()) - 60
    assert int(path.read_text()) == boots[1]
    assert own_clock(path) is own_clock(path)                  # one clock per node in a process
    path.write_text("not a number\n")                          # a damaged file: the wall clock still goes up
    other = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=60)
    assert other.returncode == 0 and int(other.stdout) >= int(time.time()) - 60


@pytest.mark.fast
def test_a_capture_from_before_the_drone_restarted_is_refused_and_the_gcs_rebinds(fleet: Path,
                                                                                  tmp_path: Path) -> None:
    first = _drone(fleet, tmp_path / "uav1.boot")
    gcs = sealed(ENVELOPE, Keyring(fleet, "gcs1"))
    seal = gcs.sealer("uav1/setpoint")
    unbound = seal(_setpoint())                               # sealed before the GCS heard the drone
    at_first = first.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
    assert _refusal(at_first, unbound) == "unbound"
    _hear(gcs, first)
    captured = seal(_setpoint(2.0))
    assert STAMP.unpack_from(captured, STAMP_AT)[0] == first.own.boot
    assert at_first(captured, None)[5][2] == 2.0
    # The drone restarts (a new process: its counter was stored; here a second counter file a start ahead).
    (tmp_path / "uav1-next.boot").write_text(f"{first.own.boot + 1}\n")
    second = _drone(fleet, tmp_path / "uav1-next.boot")
    assert second.own.boot > first.own.boot
    at_second = second.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
    assert _refusal(at_second, captured) == "restarted"      # the recording of yesterday's flight
    assert _refusal(at_second, seal(_setpoint(3.0))) == "restarted"   # the GCS has not heard the new start yet
    old_state = first.sealer("uav1/state")(_state())
    _hear(gcs, second)                                         # its next telemetry sample re-binds the GCS
    assert at_second(seal(_setpoint(4.0)), None)[5][2] == 4.0
    at_gcs = gcs.keyed_decoder(type_support(VehicleState), "uav1/state")
    assert _refusal(at_gcs, old_state) == "restarted"         # the old start's telemetry, replayed to the GCS
    counts = second.snapshot()
    assert counts["restarted"] == 2 and counts["opened"] == 1 and counts["replayed"] == 0


@pytest.mark.fast
def test_a_capture_older_than_the_bound_is_expired_and_never_enters_the_window(fleet: Path, tmp_path: Path) -> None:
    drone = _drone(fleet, tmp_path / "uav1.boot", fresh_s=0.2)
    gcs = sealed(ENVELOPE, Keyring(fleet, "gcs1"))
    _hear(gcs, drone)
    seal = gcs.sealer("uav1/setpoint")
    late, fresh = seal(_setpoint(5.0)), seal(_setpoint(6.0))
    decode = drone.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
    assert decode(fresh, None)[5][2] == 6.0
    time.sleep(0.4)                                            # any longer wait is as expired
    assert _refusal(decode, late) == "expired"
    assert _refusal(decode, late) == "expired"                # still not accepted: an expired sample marks nothing
    assert drone.snapshot()["expired"] == 2


@pytest.mark.fast
def test_fresh_s_is_validated(fleet: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="fresh_s"):
        _drone(fleet, tmp_path / "b", fresh_s=0)


@pytest.mark.fast
def test_a_caller_that_never_heard_the_drone_is_answered_stale_and_resends_once(fleet: Path, tmp_path: Path) -> None:
    """A service call sealed before the caller heard the drone (a GCS that just started, ``gcs cmd``)
    is refused as ``unbound`` and answered with a sealed ``stale`` error; the client learns the drone's
    clock from that answer and sends the same call once more, which runs once. A captured request copy
    of it, replayed after the bound, is expired; replayed after the drone restarted, restarted."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"       # a plain router: the attacker is one of its clients
    router = zenoh.open(SessionConfig(mode="router", listen=[endpoint], multicast_scouting=False,
                                      shared_memory=False).to_zenoh())
    cfg = peer = SessionConfig(mode="client", listen=[], connect=[endpoint], multicast_scouting=False,
                               shared_memory=False)
    heard: list[str] = []

    def handle(cmd: Command) -> CommandResult:
        heard.append(cmd.name)
        return CommandResult(True, "ok")
    drone_wire = _drone(fleet, tmp_path / "uav1.boot", fresh_s=1.0)
    captured: list[bytes] = []
    with Node("companion", namespace="uav1", config=cfg, wire=drone_wire) as drone, \
            Node("gcs", namespace="uav1", config=peer, wire=sealed(ENVELOPE, Keyring(fleet, "gcs1"))) as gcs:
        for node in (drone, gcs):
            threading.Thread(target=node.spin, daemon=True).start()
        tap = zenoh.open(peer.to_zenoh())
        try:
            sub = tap.declare_subscriber("@srv/uav1/command/@rq", lambda s: captured.append(s.payload.to_bytes()))
            service = drone.create_service("command", Command, CommandResult, handle)
            from zenoh_robot.services import AdaptiveRetry
            client = gcs.create_client("/uav1/command", Command, CommandResult, retry=AdaptiveRetry())
            assert client.wait_for_service(10.0)
            assert client.call(Command("hold", client_id="gcs1"), timeout=5.0).message == "ok"
            # The first try's copies (the query, and put copies every 10-50 ms until the stale answer came
            # back: one or more on a loaded machine) are all unbound; some land after the call has returned.
            assert settled(lambda: service.stale_requests, quiet_s=0.5)
            stale = service.stale_requests
            assert heard == ["hold"] and stale >= 1 and drone_wire.snapshot()["unbound"] == stale
            assert client.call(Command("land", client_id="gcs1"), timeout=5.0).message == "ok"
            assert heard == ["hold", "land"] and service.stale_requests == stale     # bound now: no refusal
            assert wait_for(lambda: len(captured) >= 2, 5.0)
            # A copy the link dropped (sealed, bound, never delivered), kept by the attacker:
            ts = type_support(Command)
            dropped = service_seal(gcs.wire, "@srv/uav1/command", ts, type_support(CommandResult)).seal_request(
                envelope.pack(ts.name, ts.hash, 99, 1, time.time_ns(), ts.encode(Command("arm", client_id="gcs1"))))
            time.sleep(1.2)                                    # past the bound: any longer wait is as expired
            before = drone_wire.snapshot()
            copies = list(captured)       # (the tap hears its own puts too)
            for copy in copies:
                tap.put("@srv/uav1/command/@rq", copy)
            tap.put("@srv/uav1/command/@rq", dropped)
            assert wait_for(lambda: drone_wire.snapshot()["expired"] == before["expired"] + 1, 5.0)
            refused = ("replayed", "duplicate", "unbound", "expired")
            moved = lambda: {k: v - before[k] for k, v in drone_wire.snapshot().items() if v != before[k]}  # noqa: E731
            assert wait_for(lambda: sum(moved().get(k, 0) for k in refused) >= len(copies) + 1, 5.0), moved()
            assert drone_wire.snapshot()["opened"] == before["opened"]
            assert heard == ["hold", "land"]
            sub.undeclare()
        finally:
            tap.close()
            router.close()
