"""Sealed samples (issue #26): every sample carries a ChaCha20-Poly1305 tag under a per-role link key,
with a replay window per (key, publisher epoch); a sample is sealed once and its repeats carry the same
bytes, which the receiver refuses as duplicates before any AEAD work. Over real Zenoh sessions, on UDP multicast (the
resilient profile's transport, no Zenoh authentication at all) and through a router: each rogue try
is refused and counted by name while the legitimate setpoint and telemetry streams keep flowing.
The attacker holds what a rogue would: a plain Zenoh session, captured bytes, another drone's or
another fleet's keys, a revoked key (crypto from ``cryptography`` directly, not from the code under test).
"""
from __future__ import annotations

import json
import logging
import os
import random
import stat
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import free_port, settled, wait_for
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from drone_contract.messages import DroneSetpoint, VehicleState
from drone_contract.streams import PROFILES
from zenoh_robot import Node, SessionConfig, envelope, qos
from zenoh_robot.keyring import Keyring, KeyringError
from zenoh_robot.message import type_support
from zenoh_robot.tools import keys
from zenoh_robot.wire import ENVELOPE, sealed
from zenoh_robot.wire.sealed import HEAD_SIZE, OVERHEAD, REPEATED, WINDOW, DuplicateSample, ReplayWindow

REFRESH_S = 0.5     # the revocation bound these tests hold the nodes to


# -- the replay window, alone ---------------------------------------------------------------------
def _offer(w: ReplayWindow, counter: int, repeated: bool = False) -> str | None:
    """What the opener does around a tag that verifies: the verdict first, then accept if fresh."""
    verdict = w.verdict(counter)
    if verdict is None:
        w.accept(counter, repeated)
    return verdict


def test_window_takes_loss_and_reordering_and_refuses_repeats_and_stale() -> None:
    w = ReplayWindow()
    rng = random.Random(26)
    counters = [c for c in range(1, 5001) if rng.random() > 0.9]      # 90 % loss
    shuffled = counters[:]
    for i in range(0, len(shuffled) - 8, 8):                           # reordered within 8
        chunk = shuffled[i:i + 8]
        rng.shuffle(chunk)
        shuffled[i:i + 8] = chunk
    assert [_offer(w, c) for c in shuffled] == [None] * len(shuffled)    # every survivor accepted once
    assert all(_offer(w, c) == "replayed" for c in counters[-50:])
    assert _offer(w, w.top - WINDOW) == "stale"
    assert _offer(w, w.top - WINDOW + 1) in (None, "replayed")           # the window's oldest slot still counts
    w2 = ReplayWindow()
    assert _offer(w2, 10) is None and _offer(w2, 10 + 5 * WINDOW) is None    # a jump past the window resets it
    assert _offer(w2, 10) == "stale" and _offer(w2, 9 + 5 * WINDOW) is None


def test_window_late_sample_within_width_is_accepted_once() -> None:
    w = ReplayWindow()
    for c in range(2, 1000):
        assert _offer(w, c) is None
    assert _offer(w, 1) is None and _offer(w, 1) == "replayed"


def test_window_names_copies_of_repeated_samples_duplicates_and_only_accept_marks() -> None:
    """A counter accepted from a repeating sealer comes back as a duplicate (its copies), one from a
    sealer that sends once as a replay; a verdict alone (a tag that then fails) marks nothing."""
    w = ReplayWindow()
    for c in range(1, 100):
        assert w.verdict(c) is None      # looked at, never accepted: a forged packet's counters
    assert w.top == -1 and all(_offer(w, c, repeated=c % 2 == 0) is None for c in range(1, 100))
    assert [_offer(w, c, repeated=True) for c in (4, 5)] == ["duplicate", "replayed"]   # the accepted flag decides
    assert w.verdict(1 + WINDOW * 3) is None and w.top == 99     # a forged jump ahead does not move the window
    assert _offer(w, 99 + WINDOW) is None and _offer(w, 99) == "stale"


# -- keys -------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fleet")
    keys.make_link_keys(d, gcs={"gcs1": ["uav1", "uav2"], "gcs2": ["uav1"]})
    return d / keys.LINK_DIR


@pytest.fixture(scope="module")
def other_fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("other")
    keys.make_link_keys(d, gcs={"gcs1": ["uav1"]})
    return d / keys.LINK_DIR


def test_keys_link_writes_private_keyrings_by_role(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "zenoh_robot.tools.cli.main", "keys", "link", "--dir", str(tmp_path),
                          "--gcs", "gcs1:uav1,uav2", "--drone", "uav3"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    link = tmp_path / keys.LINK_DIR
    master = json.loads((link / keys.LINK_MASTER).read_text())
    for k in master:
        assert k["secret"] not in out.stdout + out.stderr      # never printed
    for name in ("gcs1", "uav1", "uav2", "uav3", keys.LINK_MASTER.removesuffix(".json")):
        assert stat.S_IMODE((link / f"{name}.json").stat().st_mode) == 0o600
    held = {n: {(k["sender"], k["scope"]) for k in json.loads((link / f"{n}.json").read_text())["keys"]}
            for n in ("gcs1", "uav1", "uav2", "uav3")}
    fleet = ("fleet", "zr_link")       # the loss probes' key: every node of the fleet holds it
    assert held["uav1"] == {("uav1", "uav1"), ("gcs1", "uav1"), fleet}     # never uav2's key: it cannot forge uav2
    assert held["uav3"] == {("uav3", "uav3"), fleet}
    assert held["gcs1"] == {("uav1", "uav1"), ("uav2", "uav2"), ("gcs1", "uav1"), ("gcs1", "uav2"), fleet}
    assert "secret" not in repr(Keyring(link, "uav1")) and "Keyring('uav1', 3 keys" in repr(Keyring(link, "uav1"))
    # Rotation adds a newer key per sender; the newest seals, the old one still opens.
    old = Keyring(link, "gcs1").sealing_key("uav1")
    keys.make_link_keys(tmp_path, rotate=True, gcs={"gcs1": ["uav1", "uav2"]}, drones=["uav3"])
    ring = Keyring(link, "uav1")
    new = Keyring(link, "gcs1").sealing_key("uav1")
    assert old is not None and new is not None and new.key_id != old.key_id
    assert ring.opening_key(old.wire_id)[0] is not None and ring.opening_key(new.wire_id)[0] is not None
    os.chmod(link / "uav1.json", 0o644)
    with pytest.raises(KeyringError, match="0600"):
        Keyring(link, "uav1")


# -- a system over real Zenoh --------------------------------------------------------------------
def _configs(transport: str) -> tuple[list[SessionConfig], Any]:
    if transport == "multicast":
        group = f"239.255.74.{random.randint(100, 250)}:{free_port()}"
        return [SessionConfig.resilient("lo", group) for _ in range(3)], None
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # A plain router: it forwards sealed bytes as they are and holds no key.
    router = zenoh.open(SessionConfig(mode="router", listen=[endpoint], multicast_scouting=False,
                                      shared_memory=False).to_zenoh())
    return [SessionConfig(mode="client", listen=[], connect=[endpoint], multicast_scouting=False,
                          shared_memory=False) for _ in range(3)], router


class System:
    """uav1's companion side (setpoints in, telemetry out) and gcs1 (the reverse), sealed, each
    spinning; ``rogue`` is a plain session on the same transport."""

    def __init__(self, drone: Node, gcs: Node, rogue: zenoh.Session, fleet: Path, configs: list[SessionConfig]) -> None:
        self.drone, self.gcs, self.rogue, self.fleet, self.configs = drone, gcs, rogue, fleet, configs
        self.setpoints: list[DroneSetpoint] = []
        self.states: list[VehicleState] = []
        profiles = PROFILES["resilient"].qos
        self.setpoint_sub = drone.create_subscription(DroneSetpoint, "setpoint", self.setpoints.append,
                                                      profiles["setpoint"])
        # Another key the drone opens GCS samples on: where a captured setpoint is moved to.
        drone.create_subscription(DroneSetpoint, "goal", self.setpoints.append, profiles["setpoint"])
        gcs.create_subscription(VehicleState, "state", self.states.append, qos.SENSOR_DATA)
        self.setpoint_pub = gcs.create_publisher(DroneSetpoint, "setpoint", profiles["setpoint"])
        self.state_pub = drone.create_publisher(VehicleState, "state", qos.SENSOR_DATA)
        self.captured: list[bytes] = []
        self.captured_states: list[bytes] = []
        self._taps = [rogue.declare_subscriber("uav1/setpoint", lambda s: self.captured.append(s.payload.to_bytes())),
                      rogue.declare_subscriber("uav1/state",
                                               lambda s: self.captured_states.append(s.payload.to_bytes()))]
        self.setpoints_paused = threading.Event()     # the test publishes setpoints itself meanwhile
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._stream, daemon=True)
        self._thread.start()

    def _stream(self) -> None:
        i = 0
        while not self._stop.is_set():
            i += 1
            if not self.setpoints_paused.is_set():
                self.setpoint_pub.publish(DroneSetpoint(client_id="gcs1", x=float(i)))
            self.state_pub.publish(VehicleState(mode="OFFBOARD"))
            time.sleep(0.05)

    def still_flowing(self) -> None:
        """Both legitimate streams deliver fresh samples now."""
        sp, st = len(self.setpoints), len(self.states)
        assert wait_for(lambda: len(self.setpoints) >= sp + 5 and len(self.states) >= st + 5, 5.0), \
            f"legitimate streams stalled: setpoints {sp}->{len(self.setpoints)}, states {st}->{len(self.states)}"

    def put(self, key: str, payload: bytes, times: int = 5) -> None:
        """A rogue put, a few times spaced out: the setpoint subscription keeps the newest sample only
        (KEEP_LAST 1), so a rogue sample beside a legitimate one in one drain never reaches the seal."""
        for _ in range(times):
            self.rogue.put(key, payload)
            time.sleep(0.02)

    def stamp(self) -> tuple[int, int]:
        """uav1's boot and clock as a GCS learns them: off the newest captured state (sealed by uav1)."""
        boot, ms = struct.unpack(">II", self.captured_states[-1][17:25])
        return boot, ms

    def refused(self, node: Node, reason: str, before: int) -> bool:
        return wait_for(lambda: node.wire.snapshot()[reason] > before, 5.0)  # type: ignore[attr-defined]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for tap in self._taps:
            tap.undeclare()


@contextmanager
def system(transport: str, fleet: Path) -> Iterator[System]:
    configs, router = _configs(transport)
    rogue = zenoh.open(configs[2].to_zenoh())
    try:
        with Node("companion", namespace="uav1", config=configs[0],
                  wire=sealed(ENVELOPE, Keyring(fleet, "uav1", refresh_s=REFRESH_S))) as drone, \
                Node("gcs", namespace="uav1", config=configs[1],
                     wire=sealed(ENVELOPE, Keyring(fleet, "gcs1", refresh_s=REFRESH_S))) as gcs:
            threads = [threading.Thread(target=n.spin, daemon=True) for n in (drone, gcs)]
            for t in threads:
                t.start()
            s = System(drone, gcs, rogue, fleet, configs)
            try:
                assert wait_for(lambda: len(s.setpoints) > 3 and len(s.states) > 3, 15.0), "no sealed link formed"
                yield s
            finally:
                s.close()
    finally:
        rogue.close()
        if router is not None:
            router.close()


def _seal(secret: bytes, key_id: str, key_expr: str, inner: bytes, epoch: bytes | None = None,
          counter: int = 1, stamp: tuple[int, int] = (0, 0)) -> bytes:
    """What a holder of ``secret`` can put on ``key_expr`` (the documented layout, sealed independently:
    the subkey of the key expression, head + inner as associated data of an empty plaintext; ``stamp``:
    the owner's boot and ms the sample claims to be sealed for, 0 = never heard the owner)."""
    subkey = HKDF(algorithm=hashes.SHA256(), length=32, salt=None,
                  info=b"zenoh-robot sealed sample v1\x00" + key_expr.encode()).derive(secret)
    head = struct.pack(">B4s8sIII", 0x6A, bytes.fromhex(key_id), epoch or os.urandom(8), counter, *stamp)
    tag = ChaCha20Poly1305(subkey).encrypt(head[5:17], b"", head + inner)
    return head + inner + tag


def _key(fleet: Path, node: str, sender: str, scope: str) -> tuple[bytes, str]:
    for k in json.loads((fleet / f"{node}.json").read_text())["keys"]:
        if k["sender"] == sender and k["scope"] == scope:
            return bytes.fromhex(k["secret"]), k["id"]
    raise KeyError((node, sender, scope))


def _setpoint(client_id: str) -> bytes:
    ts = type_support(DroneSetpoint)
    body = ts.encode(DroneSetpoint(client_id=client_id, x=666.0))
    return envelope.pack(ts.name, ts.hash, 42, 1, time.time_ns(), body)


def _state() -> bytes:
    ts = type_support(VehicleState)
    return envelope.pack(ts.name, ts.hash, 42, 1, time.time_ns(), ts.encode(VehicleState(mode="FORGED")))


def _introduced(gcs: Any, drone: Any) -> Any:
    """``gcs`` (a sealed format) after it opened one of ``drone``'s sealed states, as a GCS does before it
    flies a drone: it then knows the drone's boot and clock, which what it seals in uav1/ must carry."""
    gcs.keyed_decoder(type_support(VehicleState), "uav1/state")(drone.sealer("uav1/state")(_state()), None)
    return gcs


def _forged_delivered(s: System) -> bool:
    return any(sp.x == 666.0 for sp in s.setpoints) or any(st.mode == "FORGED" for st in s.states)


TRANSPORTS = ["multicast", "router"]


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_rogue_tries_are_refused_and_counted_while_the_link_flows(transport: str, fleet: Path,
                                                                  other_fleet: Path) -> None:
    with system(transport, fleet) as s:
        drone, gcs = s.drone.wire.snapshot(), s.gcs.wire.snapshot()  # type: ignore[attr-defined]
        assert drone["replayed"] == 0 and drone["bad_tag"] == 0     # repeats are duplicates, never "replays"
        assert s.setpoint_pub.repeats > 1

        # 1. A plain session copying the GCS's client id: no seal at all.
        s.put("uav1/setpoint", _setpoint("gcs1"))
        assert s.refused(s.drone, "malformed", drone["malformed"])
        # 2. Captured sealed telemetry (sent once a sample: no repeats) re-put: refused as replays, counted.
        #    (Captured setpoints are copies of repeated samples: test_repeats_are_sealed_once_... below.)
        assert wait_for(lambda: len(s.captured_states) > 10, 5.0)
        before = s.gcs.wire.snapshot()["replayed"]  # type: ignore[attr-defined]
        for copy in s.captured_states[-10:]:
            s.put("uav1/state", copy, times=1)
        assert wait_for(lambda: s.gcs.wire.snapshot()["replayed"] >= before + 5, 5.0)  # type: ignore[attr-defined]
        # ... and moved to another key, they fail the tag (the key expression is bound).
        s.put("uav1/goal", s.captured[-1])
        assert s.refused(s.drone, "bad_tag", drone["bad_tag"])
        # 3. Another drone's key: uav2's sealing uav1 telemetry (the GCS holds it: wrong scope) and uav1
        #    setpoints (uav1 never holds it: unknown).
        secret, kid = _key(fleet, "uav2", "uav2", "uav2")
        s.put("uav1/state", _seal(secret, kid, "uav1/state", _state()))
        assert s.refused(s.gcs, "wrong_key", gcs["wrong_key"])
        s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs1")))
        assert s.refused(s.drone, "unknown_key", drone["unknown_key"])
        # ... and the drone's own key on the GCS's stream: a drone cannot forge its GCS to others.
        secret, kid = _key(fleet, "uav1", "uav1", "uav1")
        s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs1")))
        assert s.refused(s.drone, "wrong_key", drone["wrong_key"])
        # 4. A GCS of this fleet (gcs2, uav1's too) claiming gcs1's client id: the key names the sender.
        secret, kid = _key(fleet, "gcs2", "gcs2", "uav1")
        s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs1"), stamp=s.stamp()))
        assert s.refused(s.drone, "forged_claim", drone["forged_claim"])
        # 5. A node of another fleet (its own keys, same names): unknown.
        secret, kid = _key(other_fleet, "gcs1", "gcs1", "uav1")
        before = s.drone.wire.snapshot()["unknown_key"]  # type: ignore[attr-defined]
        s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs1")))
        assert s.refused(s.drone, "unknown_key", before)
        s.still_flowing()
        assert not _forged_delivered(s)
        # gcs2's honest sample (its own id) opens: the refusals above were for what was forged.
        secret, kid = _key(fleet, "gcs2", "gcs2", "uav1")
        opened = s.drone.wire.snapshot()["opened"]  # type: ignore[attr-defined]
        s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs2"), stamp=s.stamp()))
        assert wait_for(lambda: any(sp.client_id == "gcs2" for sp in s.setpoints), 5.0)
        assert s.drone.wire.snapshot()["opened"] > opened  # type: ignore[attr-defined]


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_repeats_are_sealed_once_arrive_once_and_replayed_copies_are_duplicates(transport: str, fleet: Path) -> None:
    """The resilient setpoint stream (redundancy, up to 64 copies a sample): one seal per sample, not
    per copy; every copy carries the first one's bytes; the drone opens each sample once and refuses
    the other copies as duplicates before the tag check, not as malformed; an attacker's re-put of
    captured copies is a duplicate too, never a second delivery, while the link keeps flowing."""
    with system(transport, fleet) as s:
        assert s.setpoint_pub.repeats > 1
        s.setpoints_paused.set()
        drone_wire, gcs_wire = s.drone.wire, s.gcs.wire
        assert settled(lambda: drone_wire.snapshot()["duplicate"]), "setpoint copies never stopped"  # type: ignore[attr-defined]
        gcs0, drone0 = gcs_wire.snapshot(), drone_wire.snapshot()  # type: ignore[attr-defined]
        malformed0, taken = s.setpoint_sub.counters.malformed, len(s.captured)
        n, base = 12, 1e6
        for i in range(n):
            s.setpoint_pub.publish(DroneSetpoint(client_id="gcs1", x=base + i))
            time.sleep(0.08)
        assert settled(lambda: drone_wire.snapshot()["duplicate"]), "setpoint copies never stopped"  # type: ignore[attr-defined]
        gcs1, drone1 = gcs_wire.snapshot(), drone_wire.snapshot()  # type: ignore[attr-defined]
        mine = [sp.x for sp in s.setpoints if sp.x >= base]
        assert mine and mine[-1] == base + n - 1 and len(mine) == len(set(mine)), mine   # each sample once
        assert len(mine) >= n // 2, mine
        assert gcs1["sealed"] - gcs0["sealed"] == n                      # one AEAD call a sample, not a copy
        opened = drone1["opened"] - drone0["opened"]
        assert 0 < opened <= n and opened >= len(mine) - 8              # (a dropped sample's history may bring it)
        assert drone1["duplicate"] - drone0["duplicate"] >= n            # its copies: refused, counted
        assert drone1["replayed"] == drone0["replayed"] and drone1["bad_tag"] == drone0["bad_tag"]
        assert s.setpoint_sub.counters.malformed == malformed0           # a duplicate is not malformed
        # On the wire: the copies of a sample are the same sealed bytes (one nonce a sample).
        copies = s.captured[taken:]
        nonces = {c[5:HEAD_SIZE] for c in copies}
        assert len(copies) > 2 * n and len(nonces) == n, (len(copies), len(nonces))
        assert all(c[0] & REPEATED for c in copies)
        # The attacker re-puts captured copies: duplicates, and no sample is delivered twice.
        before = drone_wire.snapshot()["duplicate"]  # type: ignore[attr-defined]
        for copy in copies[-6:] + copies[:6]:
            s.put("uav1/setpoint", copy, times=1)
        assert wait_for(lambda: drone_wire.snapshot()["duplicate"] >= before + 6, 5.0)  # type: ignore[attr-defined]
        time.sleep(0.2)
        again = [sp.x for sp in s.setpoints if sp.x >= base]
        assert again == mine, (mine, again)
        assert drone_wire.snapshot()["opened"] == drone1["opened"]  # type: ignore[attr-defined]
        s.setpoints_paused.clear()
        s.still_flowing()


def test_copies_open_once_whichever_arrives_first_and_forged_counters_do_not_poison(fleet: Path) -> None:
    """At the decoder: a repeating sealer's copies are one sample. The first copy to arrive opens (loss
    may take the others), later ones are duplicates refused without the tag check (an altered copy of
    an accepted counter is a duplicate, not bad_tag); a forged packet naming a fresh counter fails the
    tag and does not mark it, so the real sample with that counter still opens afterwards."""
    gcs_ring, drone_ring = Keyring(fleet, "gcs1"), Keyring(fleet, "uav1")
    for encrypt in (False, True):
        fmt = sealed(ENVELOPE, drone_ring)
        seal = _introduced(sealed(ENVELOPE, gcs_ring, encrypt=encrypt), fmt).sealer("uav1/setpoint", repeated=True)
        opened = fmt.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
        samples = [seal(_setpoint("gcs1")) for _ in range(6)]
        assert all(p[0] & REPEATED for p in samples)
        # Sample 0 arrives twice, 1 only as its last copy (same bytes), 2 after 3 (reordered).
        for payload in (samples[0], samples[1], samples[3], samples[2]):
            assert opened(payload, None)[5][1] == "gcs1"
        for payload in (samples[0], samples[3], samples[2], samples[0]):
            with pytest.raises(DuplicateSample):
                opened(payload, None)
        altered = bytearray(samples[1])
        altered[-1] ^= 1                                          # the tag: never checked for a duplicate
        with pytest.raises(DuplicateSample):
            opened(bytes(altered), None)
        # A forged packet with sample 4's (fresh) counter: bad tag, and sample 4 still opens, once.
        forged = bytearray(samples[4])
        forged[HEAD_SIZE + 2] ^= 0x10
        with pytest.raises(envelope.MalformedSample, match="bad_tag"):
            opened(bytes(forged), None)
        with pytest.raises(envelope.MalformedSample, match="bad_tag"):
            opened(bytes(forged), None)                           # still fresh: checked again, not a duplicate
        assert opened(samples[4], None)[5][1] == "gcs1"
        with pytest.raises(DuplicateSample):
            opened(samples[4], None)
        # The repeated flag is authenticated: a copy flagged "sent once" with a fresh counter fails its tag.
        with pytest.raises(envelope.MalformedSample, match="bad_tag"):
            opened(bytes([samples[5][0] & ~REPEATED]) + samples[5][1:], None)
        counts = fmt.snapshot()
        assert counts["opened"] == 4 + 1 and counts["duplicate"] == 4 + 1 + 1
        assert counts["bad_tag"] == 3 and counts["replayed"] == 0


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_revoked_key_is_refused_within_the_refresh_bound(transport: str, tmp_path: Path) -> None:
    keys.make_link_keys(tmp_path, gcs={"gcs1": ["uav1"], "gcs2": ["uav1"]})
    fleet = tmp_path / keys.LINK_DIR
    with system(transport, fleet) as s:
        secret, kid = _key(fleet, "gcs2", "gcs2", "uav1")
        epoch = os.urandom(8)
        for counter in range(1, 6):
            s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs2"), epoch, counter, s.stamp()),
                  times=1)
        assert wait_for(lambda: any(sp.client_id == "gcs2" for sp in s.setpoints), 5.0)
        assert keys.revoke_link_keys(tmp_path, ["gcs2"]) == [kid]
        revoked_at = time.monotonic()
        before = s.drone.wire.snapshot()["revoked"]  # type: ignore[attr-defined]
        delivered = sum(sp.client_id == "gcs2" for sp in s.setpoints)
        counter = 5
        while s.drone.wire.snapshot()["revoked"] == before and time.monotonic() - revoked_at < 5:  # type: ignore[attr-defined]
            counter += 1
            s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs2"), epoch, counter, s.stamp()),
                  times=1)
            time.sleep(0.05)
        took = time.monotonic() - revoked_at
        assert s.drone.wire.snapshot()["revoked"] > before, "the revoked key was never refused"  # type: ignore[attr-defined]
        # REFRESH_S + delivery, with a second's room for a loaded machine: the keyring's default refresh (2 s)
        # or none at all would still fail it.
        assert took < REFRESH_S + 1.0, f"revocation took {took:.2f} s (bound {REFRESH_S} s + delivery)"
        settled = sum(sp.client_id == "gcs2" for sp in s.setpoints)
        s.put("uav1/setpoint", _seal(secret, kid, "uav1/setpoint", _setpoint("gcs2"), epoch, counter + 1, s.stamp()))
        s.still_flowing()
        assert sum(sp.client_id == "gcs2" for sp in s.setpoints) == settled >= delivered


def test_sealing_adds_a_fixed_overhead_and_encrypts_on_request(fleet: Path) -> None:
    gcs_ring, drone_ring = Keyring(fleet, "gcs1"), Keyring(fleet, "uav1")
    inner = _setpoint("gcs1")
    for encrypt in (False, True):
        fmt = sealed(ENVELOPE, drone_ring)
        seal = _introduced(sealed(ENVELOPE, gcs_ring, encrypt=encrypt), fmt).sealer("uav1/setpoint")
        opened = fmt.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
        a, b = seal(inner), seal(inner)
        assert len(a) == len(inner) + OVERHEAD and a != b          # a new nonce per copy
        assert (inner in a) is (not encrypt)
        assert opened(a, None)[5][1] == "gcs1" and opened(b, None)[5][1] == "gcs1"
        with pytest.raises(envelope.MalformedSample, match="replayed"):
            opened(a, None)
        other = fmt.keyed_decoder(type_support(DroneSetpoint), "uav1/other")
        with pytest.raises(envelope.MalformedSample, match="bad_tag"):
            other(seal(inner), None)
    with pytest.raises(ValueError, match="holds no link key"):
        sealed(ENVELOPE, drone_ring).sealer("uav2/state")


def test_truncated_garbled_and_foreign_samples_are_refused_and_counted(fleet: Path, other_fleet: Path) -> None:
    """Every way a sealed sample can be wrong, at the decoder: refused by name, counted, never decoded;
    the legitimate stream opens before and after (no refusal moves the replay window)."""
    gcs_ring, drone_ring = Keyring(fleet, "gcs1"), Keyring(fleet, "uav1")
    for encrypt in (False, True):
        fmt = sealed(ENVELOPE, drone_ring)
        seal = _introduced(sealed(ENVELOPE, gcs_ring, encrypt=encrypt), fmt).sealer("uav1/setpoint")
        opened = fmt.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
        inner = _setpoint("gcs1")
        assert opened(seal(inner), None)[5][1] == "gcs1"
        good = seal(inner)
        tries: list[tuple[bytes, str]] = [
            (good[:OVERHEAD - 1], "malformed"),                         # shorter than a seal
            (good[:-1], "bad_tag"),                                     # the tag cut
            (good[:HEAD_SIZE] + good[HEAD_SIZE + 3:], "bad_tag"),       # bytes cut from the middle
            (b"", "malformed"),
            (bytes([0x00]) + good[1:], "malformed"),                    # not a seal's flags
            (bytes([good[0] ^ 1]) + good[1:], "bad_tag"),               # authenticate-only <-> encrypted
        ]
        for i in (1, 7, 15, 18, 22, HEAD_SIZE + 2, len(good) // 2, len(good) - 3):   # one bit flipped: id, epoch,
            flipped = bytearray(good)                                    # counter, boot, ms, body, tag
            flipped[i] ^= 0x10
            tries.append((bytes(flipped), "unknown_key" if i < 5 else "bad_tag"))
        secret, kid = _key(other_fleet, "gcs1", "gcs1", "uav1")
        tries.append((_seal(secret, kid, "uav1/setpoint", inner), "unknown_key"))   # another fleet's key
        secret, kid = _key(fleet, "uav1", "uav1", "uav1")
        tries.append((_seal(secret, kid, "uav1/setpoint", inner), "wrong_key"))     # the drone's own key
        for payload, reason in tries:
            before = fmt.snapshot()
            with pytest.raises(envelope.MalformedSample, match=reason):
                opened(payload, None)
            after = fmt.snapshot()
            assert after[reason] == before[reason] + 1 and after["opened"] == before["opened"], (reason, payload[:20])
        assert opened(good, None)[5][1] == "gcs1"                       # the real one still opens, once
        with pytest.raises(envelope.MalformedSample, match="replayed"):
            opened(good, None)
        assert fmt.snapshot()["replayed"] == 1


def test_fleet_probes_seal_under_the_fleet_key_and_outsiders_are_refused(fleet: Path, other_fleet: Path) -> None:
    """The loss-feedback probes (``/zr_link``, outside every drone's namespace) seal under the fleet key
    every node holds: a drone's and a GCS's open each other's; another fleet's are unknown."""
    from zenoh_robot.loss_feedback import LinkProbe
    ts = type_support(LinkProbe)
    probe = envelope.pack(ts.name, ts.hash, 9, 1, time.time_ns(), ts.encode(LinkProbe(id=1, seq=1)))
    drone, gcs = sealed(ENVELOPE, Keyring(fleet, "uav1")), sealed(ENVELOPE, Keyring(fleet, "gcs1"))
    at_gcs = gcs.keyed_decoder(ts, "zr_link")
    at_drone = drone.keyed_decoder(ts, "zr_link")
    assert at_gcs(drone.sealer("zr_link")(probe), None)[3] == 1
    assert at_drone(gcs.sealer("zr_link")(probe), None)[3] == 1
    outsider = sealed(ENVELOPE, Keyring(other_fleet, "uav1")).sealer("zr_link")
    with pytest.raises(envelope.MalformedSample, match="unknown_key"):
        at_drone(outsider(probe), None)
    with pytest.raises(ValueError, match="holds no link key"):     # no other root-namespace key seals
        drone.sealer("statistics")


def test_replay_window_refuses_old_copies_after_an_epoch_switch(fleet: Path) -> None:
    """Two publishers' epochs interleaved (the decoder's hot entry switching): each epoch keeps its own
    window, replays of either are refused, and a new epoch opens."""
    fmt = sealed(ENVELOPE, Keyring(fleet, "uav1"))
    opened = fmt.keyed_decoder(type_support(DroneSetpoint), "uav1/setpoint")
    a = _introduced(sealed(ENVELOPE, Keyring(fleet, "gcs1")), fmt).sealer("uav1/setpoint")
    b = _introduced(sealed(ENVELOPE, Keyring(fleet, "gcs1")), fmt).sealer("uav1/setpoint")
    inner = _setpoint("gcs1")
    copies = [(a(inner), b(inner)) for _ in range(50)]
    for x, y in copies:
        opened(x, None)
        opened(y, None)
    for x, y in copies[::7]:
        for payload in (x, y):
            with pytest.raises(envelope.MalformedSample, match="replayed"):
                opened(payload, None)
    assert fmt.snapshot()["replayed"] == 2 * len(copies[::7]) and fmt.snapshot()["opened"] == 100


def test_startup_line_names_the_seal_and_key_ids_never_the_keys(fleet: Path) -> None:
    import signal

    from drone_contract.link_protection import UNAUTHENTICATED, link_wire, startup_line

    before = signal.getsignal(signal.SIGHUP)
    try:
        wire, ring = link_wire(str(fleet), "uav1")     # re-read on SIGHUP: the handler is the keyring's
        assert signal.getsignal(signal.SIGHUP) is not before
        signal.raise_signal(signal.SIGHUP)
        assert ring.reloads == 2
    finally:
        signal.signal(signal.SIGHUP, before)
    assert isinstance(wire, type(sealed(ENVELOPE, ring)))
    level, line = startup_line(SessionConfig(), ring)
    assert "per-sample AEAD (ChaCha20-Poly1305, authenticated), key ids" in line
    assert all(k in line for k in ring.key_ids())
    assert UNAUTHENTICATED not in line and level == logging.INFO and "command is sealed" in line
    for k in json.loads((fleet / "uav1.json").read_text())["keys"]:
        assert k["secret"] not in line
    assert "encrypted" in startup_line(SessionConfig(), ring, encrypt=True)[1]


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_commands_are_sealed_per_sender_and_forged_or_replayed_calls_refused(transport: str, fleet: Path) -> None:
    from drone_contract.messages import Command, CommandResult
    from zenoh_robot.services import ServiceCallError

    with system(transport, fleet) as s:
        heard: list[Command] = []

        def handle(cmd: Command) -> CommandResult:
            heard.append(cmd)
            return CommandResult(True, f"ok {cmd.client_id}")
        service = s.drone.create_service("command", Command, CommandResult, handle)
        client = s.gcs.create_client("/uav1/command", Command, CommandResult)
        captured: list[bytes] = []
        tap = s.rogue.declare_subscriber("@srv/uav1/command/@rq", lambda smp: captured.append(smp.payload.to_bytes()))
        try:
            reply = client.call(Command("hold", client_id="gcs1"), timeout=5.0)
            assert reply.message == "ok gcs1" and [c.client_id for c in heard] == ["gcs1"]
            # On multicast the tap's declaration may reach the GCS's session after that first call (a CI
            # run's tap heard nothing): gcs1 calls again until the tap has a sealed copy to replay.
            deadline = time.monotonic() + 10.0
            while transport == "multicast" and not captured and time.monotonic() < deadline:
                assert client.call(Command("hold", client_id="gcs1"), timeout=5.0).message == "ok gcs1"
                time.sleep(0.2)
            legit = list(captured)      # the sealed copies of gcs1's calls (the tap hears the rogue's own puts too)
            # gcs2 (a GCS of this fleet, uav1's too) claiming gcs1's id: its own key names it.
            with Node("gcs2", namespace="uav1", config=s.configs[2],
                      wire=sealed(ENVELOPE, Keyring(s.fleet, "gcs2"))) as gcs2:
                other = gcs2.create_client("/uav1/command", Command, CommandResult)
                with pytest.raises(ServiceCallError):
                    other.call(Command("arm", client_id="gcs1"), timeout=2.0)
                assert s.drone.wire.snapshot()["forged_claim"] > 0  # type: ignore[attr-defined]
                assert other.call(Command("hold", client_id="gcs2"), timeout=5.0).message == "ok gcs2"
            # A plain session's request on the put path (or any unsealed bytes): refused before the handler.
            bad = service.bad_requests
            from zenoh_robot.message import type_support as ts_of
            ts = ts_of(Command)
            plain = envelope.pack(ts.name, ts.hash, 7, 1, time.time_ns(), ts.encode(Command("arm", client_id="gcs1")))
            s.put("@srv/uav1/command/@rq", plain)
            assert wait_for(lambda: service.bad_requests > bad, 5.0)
            # Captured sealed request copies re-put: replays, no new execution.
            runs = service.executions
            replayed = s.drone.wire.snapshot()["replayed"]  # type: ignore[attr-defined]
            if legit:    # the put path carries calls on multicast (always) and for AdaptiveRetry clients
                for copy in legit[:3]:
                    s.put("@srv/uav1/command/@rq", copy, times=1)
                assert wait_for(lambda: s.drone.wire.snapshot()["replayed"] > replayed, 5.0)  # type: ignore[attr-defined]
            else:
                assert transport == "router"
            assert service.executions == runs
            assert all(c.client_id in ("gcs1", "gcs2") for c in heard) and "arm" not in [c.name for c in heard]
            s.still_flowing()
        finally:
            tap.undeclare()


def test_an_action_goal_is_bound_to_its_sealing_gcs_as_a_command_is(fleet: Path) -> None:
    """A goal's client_id sits inside the SendGoal request (goal_id, goal): the seal checks it there, so a
    GCS key cannot send a goal in another GCS's name (the drone's takeoff/goto/land actions)."""
    from drone_contract.actions import action_types
    from zenoh_robot.services import ServiceCallError
    from zenoh_robot.wire.sealed import claim_index

    takeoff = action_types().takeoff
    assert claim_index(type_support(takeoff.send_goal.request)) == (1, 0)
    assert claim_index(type_support(takeoff.get_result.request)) is None
    with system("router", fleet) as s:
        ran: list[str] = []

        def execute(handle: Any) -> Any:
            ran.append(handle.request.client_id)
            handle.succeed()
            return takeoff.Result(success=True, message="ok")
        s.drone.create_action_server(takeoff, "takeoff", execute)
        own = s.gcs.create_action_client(takeoff, "/uav1/takeoff")
        assert own.wait_for_server(10.0)
        res = own.send_goal(takeoff.Goal(client_id="gcs1", altitude_m=3.0), timeout=10.0)
        assert res is not None and res.result.success and ran == ["gcs1"]
        forged = s.drone.wire.snapshot()["forged_claim"]  # type: ignore[attr-defined]
        with Node("gcs2", namespace="uav1", config=s.configs[2],
                  wire=sealed(ENVELOPE, Keyring(s.fleet, "gcs2"))) as gcs2:
            threading.Thread(target=gcs2.spin, daemon=True).start()
            other = gcs2.create_action_client(takeoff, "/uav1/takeoff", goal_timeout=2.0)
            assert other.wait_for_server(10.0)
            with pytest.raises((ServiceCallError, TimeoutError)):   # no reply: the request never opened
                other.send_goal_async(takeoff.Goal(client_id="gcs1", altitude_m=3.0)).result(4.0)
            assert s.refused(s.drone, "forged_claim", forged)
            assert other.send_goal(takeoff.Goal(client_id="gcs2", altitude_m=3.0), timeout=10.0) is not None
        assert ran == ["gcs1", "gcs2"]
