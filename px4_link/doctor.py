"""``zenoh-robot doctor --px4 DEVICE``: can this machine reach its flight controller over that port?

A plugin of the doctor (entry point ``zenoh_robot.doctor``: the doctor itself knows no MAVLink). Its
checks, one verdict each: the connection's form; for a serial port, that the device exists, is a tty
and this user may open it (the ``dialout`` group); then the link itself: PX4's heartbeats within the
wait, or why not (nothing arrives; bytes arrive but no frame parses at this baud, with the rate to try);
then PX4's firmware version (AUTOPILOT_VERSION); then PX4's modes (AVAILABLE_MODES: how many, their names,
registered external modes by theirs).
"""
from __future__ import annotations

import argparse

from .connection_url import Px4UrlError, check_serial_device, parse_px4_url
from .link import Px4Link
from .mode_list import AvailableMode

WAIT_S = 4.0   # PX4 sends a heartbeat a second; a wrong baud's garbage needs ~2 kB to be named

Check = tuple[str, str, str]    # name, ok | warn | fail, detail


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--px4", metavar="URL",
                        help="also check the flight controller's link: a serial device with an optional baud "
                             "(/dev/ttyACM0, /dev/serial0:921600), or any --px4 form the companion takes")


def checks(args: argparse.Namespace) -> list[Check]:
    spec = getattr(args, "px4", None)
    if not spec:
        return []
    try:
        url = parse_px4_url(spec)
    except Px4UrlError as exc:
        return [("px4", "fail", str(exc))]
    out: list[Check] = []
    if url.is_serial:
        try:
            check_serial_device(url)
        except Px4UrlError as exc:
            return [("px4 device", "fail", str(exc))]
        out.append(("px4 device", "ok", f"{url.device}: a serial device this user may open"))
    where = f"{url.device} at {url.baud} baud" if url.is_serial else spec
    try:
        with Px4Link(spec, heartbeat_timeout=WAIT_S) as link:
            if link.wait_connected(WAIT_S):
                s = link.state
                out.append(("px4 link", "ok", f"heartbeats from system {s.system_id} component {s.component_id} "
                                              f"on {where}, mode {s.mode}{', ARMED' if s.armed else ''}"))
                version = link.firmware_version(WAIT_S)
                out.append(("px4 firmware", "ok", f"PX4 {version}") if version is not None else
                           ("px4 firmware", "warn", "no AUTOPILOT_VERSION within "
                                                    f"{WAIT_S:g} s (MAV_CMD_REQUEST_MESSAGE 148 unanswered)"))
                out.append(modes_check(link.available_modes(WAIT_S), link.modes.refused))
            else:
                why = link.not_connected_reason()
                if why == "no vehicle connected":
                    why = (f"no MAVLink heartbeat on {where} in {WAIT_S:g} s: is PX4 powered, and does the port "
                           "run MAVLink (MAV_1_CONFIG on TELEM2)?")
                out.append(("px4 link", "fail", why))
    except (OSError, ValueError) as exc:
        out.append(("px4 link", "fail", f"cannot open {where}: {exc}"))
    return out


def modes_check(modes: list[AvailableMode], refused: int | None) -> Check:
    """One line for PX4's AVAILABLE_MODES: the count, the selectable modes' names (a registered external mode
    by its own), how many external slots are free."""
    if not modes:
        why = (f"PX4 refused MAV_CMD_REQUEST_MESSAGE 435 (MAV_RESULT {refused}): a PX4 before v1.15 has no mode list"
               if refused is not None else f"no AVAILABLE_MODES within {WAIT_S:g} s")
        return ("px4 modes", "warn", why)
    free = sum(1 for m in modes if m.external is not None and not m.selectable)
    external = [m.name for m in modes if m.external is not None and m.selectable]
    names = [m.name for m in modes if m.selectable and m.external is None]
    text = f"{len(modes)} modes, {len(names) + len(external)} selectable: {', '.join(names)}"
    if external:
        text += f"; external: {', '.join(external)}"
    return ("px4 modes", "ok", text + f"; {free} external slot{'s' if free != 1 else ''} free")
