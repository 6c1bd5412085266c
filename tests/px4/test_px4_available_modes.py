"""PX4's mode list over MAVLink (issue #41): AVAILABLE_MODES (435), CURRENT_MODE (436), AVAILABLE_MODES_MONITOR
(437), as PX4's mavlink module sends them (streams/AVAILABLE_MODES.hpp, CURRENT_MODE.hpp) and px4_link reads
them; against the simulator and a scripted PX4 over real localhost UDP, the frames checked byte by byte
against MAVLink's development.xml (pymavlink's ``common`` lacks these three messages)."""
from __future__ import annotations

import socket
import struct
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pymavlink
import pytest
from px4_helpers import sim_and_link

from px4_link import Px4Link
from px4_link.doctor import modes_check
from px4_link.mode_list import AvailableMode, mode_entry
from px4_link.modes import (
    decode_custom_mode,
    encode_custom_mode,
    external_mode_number,
    mode_to_main_sub,
    normalize_mode_name,
)
from px4_link.sim.available_modes import AvailableModes
from px4_link.wire import Encoder, Parser

# PX4's list on a multicopter (ModeManagement::getModeStatus): mode_util::getValidNavStates() in nav-state order,
# then the eight external slots. Standard modes per mode_util::getStandardModeFromNavState for a rotary wing.
PX4_LIST = [
    ("MANUAL", 0), ("ALTCTL", 4), ("POSCTL", 1), ("AUTO.MISSION", 6), ("AUTO.LOITER", 0), ("AUTO.RTL", 5),
    ("POSCTL.SLOW", 0), ("ALTITUDE_CRUISE", 0), ("ACRO", 0), ("TERMINATION", 0), ("OFFBOARD", 0),
    ("STABILIZED", 0), ("AUTO.TAKEOFF", 8), ("AUTO.LAND", 7), ("AUTO.FOLLOW_TARGET", 0), ("AUTO.PRECLAND", 0),
    ("POSCTL.ORBIT", 2), ("AUTO.VTOL_TAKEOFF", 0),
    *((f"EXTERNAL{n}", 0) for n in range(1, 9)),
]
ADVANCED, NOT_USER_SELECTABLE = 1, 2
DEVELOPMENT_XML = Path(pymavlink.__file__).parent / "dialects" / "v20" / "development.xml"


# ------------------------------------------------------------------ units
@pytest.mark.fast   # in-process only (conftest: the fast tier)
@pytest.mark.parametrize("n", range(1, 9))
def test_an_external_modes_custom_mode_decodes_as_px4_encodes_it(n: int) -> None:
    # px4_custom_mode.h: NAVIGATION_STATE_EXTERNALn -> main AUTO (4), sub PX4_CUSTOM_SUB_MODE_EXTERNALn (10 + n).
    custom = ((10 + n) << 24) | (4 << 16)
    assert decode_custom_mode(custom) == f"EXTERNAL{n}"
    assert external_mode_number(custom) == n
    assert encode_custom_mode(f"EXTERNAL{n}") == custom
    assert mode_to_main_sub(normalize_mode_name(f"external{n}")) == (4, 10 + n)   # DO_SET_MODE's params


@pytest.mark.fast   # in-process only (conftest: the fast tier)
def test_internal_modes_keep_their_names_and_out_of_range_subs_stay_unknown() -> None:
    assert external_mode_number(encode_custom_mode("AUTO.LOITER")) is None
    assert external_mode_number(6 << 16) is None
    assert decode_custom_mode((4 << 16) | (19 << 24)).startswith("UNKNOWN")   # past EXTERNAL8
    assert decode_custom_mode((4 << 16) | (7 << 24)).startswith("UNKNOWN")    # RTGS, removed from PX4
    assert decode_custom_mode(11 << 16) == "ALTITUDE_CRUISE"                   # PX4_CUSTOM_MAIN_MODE_ALTITUDE_CRUISE


@pytest.mark.fast   # in-process only (conftest: the fast tier)
def test_an_entrys_name_is_the_registered_one_only_for_a_registered_external_mode() -> None:
    class Msg:
        def __init__(self, custom: int, props: int, name: bytes, index: int = 19) -> None:
            self.mode_index, self.number_modes, self.standard_mode = index, 26, 0
            self.custom_mode, self.properties, self.mode_name = custom, props, name
    ext1 = encode_custom_mode("EXTERNAL1")
    assert mode_entry(Msg(ext1, 0, b"Follow Me")).name == "Follow Me"
    free = mode_entry(Msg(ext1, NOT_USER_SELECTABLE, b"(Mode not available)"))
    assert free.name == "EXTERNAL1" and not free.selectable and free.external == 1
    assert mode_entry(Msg(encode_custom_mode("AUTO.LOITER"), ADVANCED, b"Hold", 5)).name == "AUTO.LOITER"
    assert mode_entry(Msg(12 << 16, ADVANCED, b"Some New Mode", 9)).name == "Some New Mode"


# ------------------------------------------------------------------ the frames, against development.xml
def _x25(data: bytes, crc: int = 0xFFFF) -> int:
    for b in data:
        tmp = (b ^ (crc & 0xFF)) & 0xFF
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


_SIZES = {"char": 1, "uint8_t": 1, "int8_t": 1, "uint16_t": 2, "int16_t": 2, "uint32_t": 4, "int32_t": 4,
          "float": 4, "uint64_t": 8, "int64_t": 8, "double": 8}
_STRUCT = {"char": "s", "uint8_t": "B", "uint32_t": "I"}


def _definition(msg_id: int) -> tuple[str, list[tuple[str, str, int]], int]:
    """(name, wire-ordered fields (type, name, array length), crc_extra) of a message in development.xml,
    by MAVLink's rules: fields sorted by type size, largest first (stable); crc_extra over the name and fields."""
    root = ET.parse(DEVELOPMENT_XML).getroot()
    msg = next(m for m in root.iter("message") if int(m.get("id", -1)) == msg_id)
    fields = []
    for f in msg.findall("field"):
        t = f.get("type", "")
        base, _, rest = t.partition("[")
        fields.append((base, f.get("name", ""), int(rest.rstrip("]")) if rest else 0))
    wire = sorted(fields, key=lambda f: -_SIZES[f[0]])
    text = (msg.get("name", "") + " ").encode()
    crc = _x25(text)
    for base, name, length in wire:
        crc = _x25(f"{base} {name} ".encode(), crc)
        if length:
            crc = _x25(bytes([length]), crc)
    return msg.get("name", ""), wire, (crc & 0xFF) ^ (crc >> 8)


def _decode_frame(frame: bytes) -> tuple[int, dict[str, object]]:
    """A MAVLink 2 frame decoded by hand from development.xml: (message id, fields); asserts its CRC."""
    assert frame[0] == 0xFD, "MAVLink 2"
    length, msg_id = frame[1], frame[7] | (frame[8] << 8) | (frame[9] << 16)
    payload = frame[10:10 + length]
    _, wire, crc_extra = _definition(msg_id)
    (crc,) = struct.unpack_from("<H", frame, 10 + length)
    assert crc == _x25(frame[1:10 + length] + bytes([crc_extra])), f"CRC of message {msg_id}"
    fmt = "<" + "".join(f"{n}s" if n else _STRUCT[t] for t, _, n in wire)
    full = payload + bytes(struct.calcsize(fmt) - len(payload))   # MAVLink 2 trims trailing zeros
    values = struct.unpack(fmt, full)
    return msg_id, {name: v for (_, name, _), v in zip(wire, values, strict=True)}


@pytest.mark.fast   # in-process only (conftest: the fast tier)
def test_the_three_messages_are_as_development_xml_defines_them() -> None:
    # The wire order (uint32 first) and crc_extra the frames below are checked against.
    name, wire, crc_extra = _definition(435)
    assert name == "AVAILABLE_MODES"
    assert [f[1] for f in wire] == ["custom_mode", "properties", "number_modes", "mode_index", "standard_mode",
                                    "mode_name"]
    assert wire[-1] == ("char", "mode_name", 35)
    assert _definition(436)[1][0][1] == "custom_mode" and _definition(437)[1] == [("uint8_t", "seq", 0)]
    # What the link encodes with: pymavlink's development dialect, whose crc_extra is the XML's.
    from pymavlink.dialects.v20 import development
    assert development.MAVLink_available_modes_message.crc_extra == crc_extra
    assert development.MAVLink_current_mode_message.crc_extra == _definition(436)[2]
    assert development.MAVLink_available_modes_monitor_message.crc_extra == _definition(437)[2]


@pytest.mark.fast   # in-process only (conftest: the fast tier)
def test_the_parser_decodes_them_next_to_common_and_rejects_a_bad_crc() -> None:
    frames: list[bytes] = []
    enc = Encoder(frames.append, 1, 1)
    enc.send(enc.available_modes_encode(26, 19, 0, encode_custom_mode("EXTERNAL1"), 0, b"Follow Me"))
    enc.send(enc.current_mode_encode(0, encode_custom_mode("EXTERNAL1"), encode_custom_mode("AUTO.LOITER")))
    enc.send(enc.heartbeat_encode(2, 12, 1, 0, 3))
    parser = Parser()
    got = parser.feed(b"".join(frames))
    assert [m.get_type() for m in got] == ["AVAILABLE_MODES", "CURRENT_MODE", "HEARTBEAT"]
    assert [m.get_seq() for m in got] == [0, 1, 2]   # one sequence across both dialects
    assert got[0].mode_name == "Follow Me" and got[1].intended_custom_mode == encode_custom_mode("AUTO.LOITER")
    assert parser.unknown_messages == 0
    broken = bytearray(frames[0])
    broken[12] ^= 0xFF
    assert parser.feed(bytes(broken), datagram=True) == []
    assert parser.crc_errors == 1


@pytest.mark.fast   # in-process only (conftest: the fast tier)
def test_with_signing_they_must_be_signed_too() -> None:
    from px4_link.wire import setup_signing
    key = bytes(range(32))
    signed: list[bytes] = []
    plain: list[bytes] = []
    enc, enc_plain = Encoder(signed.append, 1, 1), Encoder(plain.append, 1, 1)
    setup_signing(enc.mav, key)
    for e in (enc, enc_plain):
        e.send(e.available_modes_monitor_encode(3))
    parser = Parser()
    for mav in parser.decoders:
        setup_signing(mav, key, sign_outgoing=False)
    assert [m.seq for m in parser.feed(signed[0], datagram=True)] == [3]
    assert parser.feed(plain[0], datagram=True) == [] and parser.bad_signatures == 1


# ------------------------------------------------------------------ against the simulator
def _captured(link: Px4Link, ids: set[int]) -> list[bytes]:
    frames: list[bytes] = []

    def keep(frame: bytes) -> None:
        if frame[0] == 0xFD and frame[7] | (frame[8] << 8) | (frame[9] << 16) in ids:
            frames.append(frame)
    link.add_frame_listener(keep)
    return frames


def test_the_link_asks_for_every_mode_and_names_them_as_px4_maps_them() -> None:
    with sim_and_link(armable=False) as (sim, link, _events):
        assert link.available_modes(5)   # asked by the link itself once connected
        asked: list[int] = []
        real = sim.available_modes.requested
        sim.available_modes.requested = lambda index: (asked.append(index), real(index))[1]
        frames = _captured(link, {435})
        link.modes.refresh()   # asked again, recorded this time (the first went out at connect)
        assert link.wait_until(lambda: len(frames) == 26 and link.modes.complete, 5), len(frames)
        modes = link.available_modes()
        assert asked == [0]                                   # param2 = 0: all of them, as QGC asks
        assert [(m.name, m.standard_mode) for m in modes] == PX4_LIST
        assert [m.mode_index for m in modes] == list(range(1, 27))
        by_name = {m.name: m for m in modes}
        assert not by_name["TERMINATION"].selectable          # can_set_nav_states_mask leaves it out
        assert [n for n, m in by_name.items() if not m.advanced] == ["ALTCTL", "POSCTL"] + [
            f"EXTERNAL{n}" for n in range(1, 9)]              # mode_util::isAdvanced
        assert all(not by_name[f"EXTERNAL{n}"].selectable for n in range(1, 9))   # free slots
        assert by_name["AUTO.LOITER"].custom_mode == encode_custom_mode("AUTO.LOITER")
        assert link.stats.unsolicited_acks == 0 and link.stats.unknown_messages == 0   # our ACK was claimed
        # Byte level: every frame as development.xml has it; mode_name only for a non-standard mode.
        decoded = [_decode_frame(f)[1] for f in frames]
        assert [d["mode_index"] for d in decoded] == list(range(1, 27))
        assert {d["number_modes"] for d in decoded} == {26}
        names = {decode_custom_mode(int(d["custom_mode"])): bytes(d["mode_name"]).rstrip(b"\0") for d in decoded}
        assert names["AUTO.LOITER"] == b"Hold" and names["OFFBOARD"] == b"Offboard"   # mode_util::nav_state_names
        assert names["AUTO.RTL"] == b"" and names["POSCTL"] == b""                    # standard: no name
        assert names["EXTERNAL3"] == b"(Mode not available)"
        assert link.modes.requests_sent == 2


def test_one_mode_by_its_index_and_an_index_past_the_list_as_px4_answers() -> None:
    with sim_and_link(armable=False) as (sim, link, _events):
        assert link.available_modes(5)
        frames = _captured(link, {435})
        link.send_command(512, 435, 6)   # Return, alone
        assert link.wait_until(lambda: len(frames) == 1, 2)
        one = _decode_frame(frames[0])[1]
        assert (one["mode_index"], one["number_modes"], one["standard_mode"]) == (6, 26, 5)
        from px4_link.commands import CommandDenied
        with pytest.raises(CommandDenied):   # request_message returns false: DENIED
            link.send_command(512, 435, 27, retries=0)


def test_current_mode_follows_a_mode_change() -> None:
    with sim_and_link() as (sim, link, _events):
        frames = _captured(link, {436})
        assert link.wait_until(lambda: link.modes.current is not None, 3)
        cur = link.modes.current
        assert (cur.name, cur.intended_name, cur.standard_mode) == ("AUTO.LOITER", "AUTO.LOITER", 0)
        link.action.set_mode("POSCTL")
        changed = time.monotonic()
        assert link.wait_until(lambda: link.modes.current.name == "POSCTL", 4)
        # PX4 sends CURRENT_MODE on its 0.5 Hz schedule, not on the change itself: within one period (2 s).
        assert time.monotonic() - changed < 3.0
        cur = link.modes.current
        assert (cur.custom_mode, cur.intended_custom_mode, cur.standard_mode) == (3 << 16, 3 << 16, 1)
        d = _decode_frame(frames[-1])[1]
        assert (d["custom_mode"], d["intended_custom_mode"], d["standard_mode"]) == (3 << 16, 3 << 16, 1)
        t0 = time.monotonic()
        n = len(frames)
        assert link.wait_until(lambda: len(frames) >= n + 2, 6)
        assert 1.5 < time.monotonic() - t0 < 5.5      # 0.5 Hz: two more in 2-4 s (and a loaded machine's slack)


def test_current_mode_keeps_the_users_intention_through_a_failsafe() -> None:
    from px4_link import PositionTarget
    with sim_and_link() as (sim, link, _events):
        link.action.arm()
        link.offboard.set_setpoint(PositionTarget(0, 0, -3.0, yaw=0.0))
        link.offboard.start()
        assert sim.wait_for(lambda s: s.altitude > 2.7, 8), sim.position
        link.offboard.stop_stream()   # PX4 leaves OFFBOARD for Return (COM_OBL_RC_ACT 0 without RC)
        assert sim.wait_for(lambda s: s.mode == "AUTO.RTL", 5.0), sim.mode
        # CURRENT_MODE.hpp: custom_mode from nav_state_display, intended from nav_state_user_intention.
        assert link.wait_until(lambda: link.modes.current.name == "AUTO.RTL", 4), link.modes.current
        cur = link.modes.current
        assert (cur.intended_name, cur.standard_mode) == ("OFFBOARD", 5), cur   # RTL: SAFE_RECOVERY


def test_a_registered_mode_is_announced_by_the_monitor_and_asked_for_again() -> None:
    with sim_and_link(armable=False) as (sim, link, _events):
        monitors = _captured(link, {437})
        assert link.available_modes(5) and link.modes.requests_sent == 1
        time.sleep(3.6)
        assert monitors == []            # PX4 sends the monitor only once its list changed
        nav_state = sim.register_external_mode("Follow Me")
        assert nav_state == 23
        assert link.wait_until(lambda: any(m.name == "Follow Me" for m in link.available_modes()), 6)
        assert link.modes.requests_sent == 2
        assert _decode_frame(monitors[0])[1] == {"seq": 1}
        mode = next(m for m in link.available_modes() if m.name == "Follow Me")
        assert mode == AvailableMode(19, 0, ((10 + 1) << 24) | (4 << 16), "Follow Me", 0)   # not advanced
        status, line = modes_check(link.available_modes(), link.modes.refused)[1:]
        assert status == "ok" and line.startswith("26 modes, 18 selectable:") and "external: Follow Me" in line
        assert "7 external slots free" in line
        sim.unregister_external_mode(nav_state)
        assert link.wait_until(lambda: not any(m.name == "Follow Me" for m in link.available_modes())
                               and link.modes.complete, 6)
        assert _decode_frame(monitors[-1])[1] == {"seq": 2}


def test_a_request_is_counted_before_its_answer_can_arrive() -> None:
    """The request is counted before it goes: on a fast link the answer completes the list (the receive
    thread) while send_message has not returned yet (rehearsal 18 saw the list complete and the count 0).
    Shown deterministically: the send holds until the answer is in, and reads the count then."""
    with sim_and_link(armable=False) as (sim, link, _events):
        assert link.available_modes(5)
        core = link.modes._core
        send = core.send_message
        counted_at_answer: list[int] = []

        def send_and_wait_for_the_answer(msg: Any) -> Any:
            out = send(msg)
            if getattr(msg, "command", None) == 512 and getattr(msg, "param1", None) == 435:   # AVAILABLE_MODES
                link.wait_until(lambda: any(m.name == "Follow Me" for m in link.modes.available()), 5.0)
                counted_at_answer.append(link.modes.requests_sent)
            return out
        core.send_message = send_and_wait_for_the_answer
        try:
            sim.register_external_mode("Follow Me")        # the monitor: the link asks again
            assert link.wait_until(lambda: bool(counted_at_answer), 8), "no second request"
        finally:
            core.send_message = send
        assert counted_at_answer[0] == 2


# ------------------------------------------------------------------ a scripted PX4 flying an external mode
class ScriptedPx4:
    """A PX4 reduced to what the mode list needs, on a UDP socket: HEARTBEAT and CURRENT_MODE in ``mode``,
    AVAILABLE_MODES on request from the simulator's list (with registrations), or ``refuse_with`` (an older PX4:
    DENIED) as the ACK."""

    def __init__(self, target_port: int, modes: AvailableModes, mode: str, refuse_with: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.target = ("127.0.0.1", target_port)
        self.enc = Encoder(lambda data: self.sock.sendto(data, self.target), 1, 1)
        self.modes, self.mode, self.refuse_with = modes, mode, refuse_with
        self.requests = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        parser = Parser()
        next_beat = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_beat:
                custom = encode_custom_mode(self.mode)
                self.enc.send(self.enc.heartbeat_encode(2, 12, 1 | 4 | 8 | 16, custom, 3))
                self.enc.send(self.enc.current_mode_encode(0, custom, custom))
                next_beat = now + 0.5
            try:
                data, _ = self.sock.recvfrom(2048)
            except OSError:
                continue
            for m in parser.feed(data, datagram=True):
                if m.get_type() == "COMMAND_LONG" and m.command == 512 and int(m.param1) == 435:
                    self.requests += 1
                    if self.refuse_with is None:
                        entries = self.modes.entries()
                        for i, e in enumerate(entries, 1):
                            self.enc.send(self.enc.available_modes_encode(len(entries), i, e.standard_mode,
                                                                          e.custom_mode, e.properties,
                                                                          e.mode_name.encode()))
                    self.enc.send(self.enc.command_ack_encode(512, self.refuse_with or 0, 0, 0,
                                                              m.get_srcSystem(), m.get_srcComponent()))

    def __enter__(self) -> ScriptedPx4:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


@contextmanager
def _scripted(mode: str, refuse_with: int | None = None) -> Iterator[tuple[ScriptedPx4, Px4Link]]:
    modes = AvailableModes()
    modes.register("Survey")
    modes.register("Follow Me")
    with Px4Link("udpin:127.0.0.1:0") as link, ScriptedPx4(link.local_port, modes, mode, refuse_with) as px4:
        assert link.wait_connected(5)
        yield px4, link


def test_the_state_names_an_external_mode_by_its_registered_name() -> None:
    with _scripted("EXTERNAL2") as (_px4, link):
        assert link.state.mode == "EXTERNAL2"        # what px4_zenoh calls nav_state 24 too
        assert link.wait_until(lambda: link.state.mode_name == "Follow Me", 5), link.state
        assert link.wait_until(lambda: link.modes.current is not None
                               and link.modes.current.name == "Follow Me", 3)
        assert [m.name for m in link.available_modes() if m.selectable and m.external] == ["Survey", "Follow Me"]
    with _scripted("AUTO.LOITER") as (_px4, link):
        assert link.available_modes(5)
        assert link.state.mode == "AUTO.LOITER" and link.state.mode_name is None   # PX4's own: unchanged


def test_a_px4_without_the_list_is_asked_once_and_the_doctor_says_so() -> None:
    with _scripted("AUTO.LOITER", refuse_with=2) as (px4, link):
        assert link.available_modes(3) == []
        assert link.modes.refused == 2 and px4.requests == 1
        assert link.stats.unsolicited_acks == 0
        status, why = modes_check([], link.modes.refused)[1:]
        assert status == "warn" and "before v1.15" in why
