"""The command set a GCS may send a drone: one table, read by the companion's command desk and the GCS CLI.

A command is a ``Command`` message (drone_contract.messages) sent to the drone's ``command`` service.
``CommandName`` is the one list of names; ``COMMAND_SPECS`` says, per command, what its arguments
mean and whether the sender must hold control. The companion refuses a name that is not here and
names the ones that are; ``gcs cmd`` offers exactly these (and ``offboard``, an alias the CLI keeps
for typing comfort, resolved by ``resolve_cli_name``).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

HAND_OVER_S = 10.0   # how long an offer of control (hand_over) waits for the named GCS's take_control


# The drone's command service: ``<drone id>/command`` (Command -> CommandResult).
COMMAND_SERVICE = "command"

# How an offboard_start refusal for want of the sender's setpoints begins: the one refusal that
# passes by itself (the stream has not reached the drone yet, e.g. a lossy link at start-up), so a
# mission may ask again while it streams.
NO_SETPOINTS_YET = "no recent setpoints"
# The other one that passes by itself: PX4 has sent no local position yet (it sends LOCAL_POSITION_NED only
# once its estimator has one: seconds after boot, longer without GPS; px4_link/targets.py refuses a position
# target until then). A swarm start-up on a loaded machine met it (one drone of ten refused at once).
POSITION_UNKNOWN = "vehicle position unknown"


class CommandName(enum.StrEnum):
    ARM = "arm"
    DISARM = "disarm"
    TAKEOFF = "takeoff"
    LAND = "land"
    HOLD = "hold"
    RTL = "rtl"
    OFFBOARD_START = "offboard_start"
    OFFBOARD_STOP = "offboard_stop"
    SET_PARAM = "set_param"
    TAKE_CONTROL = "take_control"
    RELEASE_CONTROL = "release_control"
    HAND_OVER = "hand_over"


@dataclass(frozen=True)
class CommandSpec:
    name: CommandName
    help: str
    value: str = ""          # what Command.value carries ("" when unused)
    text: str = ""           # what Command.text carries
    force: str = ""          # what Command.force means for this command
    claims_control: bool = True   # the sender must hold control, or takes it when nobody does


COMMAND_SPECS: dict[CommandName, CommandSpec] = {s.name: s for s in (
    CommandSpec(CommandName.ARM, "arm the motors (never into OFFBOARD)"),
    CommandSpec(CommandName.DISARM, "disarm", force="disarm in flight (refused unless the companion allows it)"),
    CommandSpec(CommandName.TAKEOFF, "AUTO.TAKEOFF to an altitude", value="altitude above home, m (0.5..120)"),
    CommandSpec(CommandName.LAND, "AUTO.LAND"),
    CommandSpec(CommandName.HOLD, "AUTO.LOITER (hold position)"),
    CommandSpec(CommandName.RTL, "AUTO.RTL"),
    CommandSpec(CommandName.OFFBOARD_START, "start an OFFBOARD session from the sender's recent setpoints"),
    CommandSpec(CommandName.OFFBOARD_STOP, "end the OFFBOARD session: AUTO.LOITER"),
    CommandSpec(CommandName.SET_PARAM, "set a PX4 parameter on the companion's allow-list",
                value="parameter value", text="parameter name"),
    CommandSpec(CommandName.TAKE_CONTROL, "become the GCS in control, or confirm a hand-over offered to this GCS",
                force="take over from another GCS"),
    CommandSpec(CommandName.RELEASE_CONTROL, "give control up; during an OFFBOARD session the drone holds "
                "(AUTO.LOITER) first", text="optional: a GCS id to hand over to instead (as hand_over)",
                claims_control=False),
    CommandSpec(CommandName.HAND_OVER, "offer control to another GCS, which confirms with take_control within "
                f"{HAND_OVER_S:g} s; the sender keeps control until then", text="the GCS id to hand over to",
                claims_control=False),
)}
COMMANDS: tuple[str, ...] = tuple(str(n) for n in CommandName)
# What `gcs cmd` accepts: the contract's names plus the short alias `offboard`.
CLI_ALIASES = {"offboard": CommandName.OFFBOARD_START}
CLI_COMMANDS: tuple[str, ...] = (*COMMANDS[:6], "offboard", *COMMANDS[6:])


def command_name(text: str) -> CommandName | None:
    """The command ``text`` names, or None when it names none."""
    try:
        return CommandName(text)
    except ValueError:
        return None


def resolve_cli_name(text: str) -> CommandName:
    """A `gcs cmd` word to its command (ValueError for an unknown one)."""
    return CLI_ALIASES.get(text) or CommandName(text)
