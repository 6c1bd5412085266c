"""Which external-mode topics PX4's zenoh bridge delivers where they belong.

PX4 main 2026-03 (02e73e3b, also 1.17's module) builds each ``/fmu/in`` subscriber from the message *type*
(src/modules/zenoh, ``genSubscriber(type)``): a topic whose type's default uORB topic is another one lands
there. For external modes that is
- ``/fmu/in/config_control_setpoints`` (VehicleControlMode) -> uORB ``vehicle_control_mode``: it overwrites
  the commander's control mode (flag_armed=0 ...) until the commander publishes again, up to 500 ms;
- ``/fmu/in/config_overrides_request`` (ConfigOverrides) -> uORB ``config_overrides``: the commander's own
  output, rewritten within 500 ms, never seen as a request;
- ``/fmu/in/vehicle_command_mode_executor`` (VehicleCommand) -> uORB ``vehicle_command``: an executor's
  command skips the executor-in-charge check.
PX4 PR #26564 maps them by topic name. Nothing on the wire tells the two builds apart: the tokens announce
the same keys and types either way, and the zenoh module publishes no version. So a PX4 is assumed to have
the bug unless the user says it is fixed (``BridgePolicy(fixed=True)``, ``PX4_ZENOH_BRIDGE_FIXED=1``). A PX4
that does not announce such a topic gets nothing on it either way (no token, no key: ``ExternalMode`` sends
only on keys PX4 announced).
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from px4_zenoh.topics import MISROUTED, Px4Topic

ENV_FIXED = "PX4_ZENOH_BRIDGE_FIXED"
FIX = "PX4 PR #26564 (zenoh: map /fmu/in topics by topic name)"


class BridgeBugError(RuntimeError):
    """Refused: the message would land on the wrong uORB topic in this PX4."""


@dataclass(frozen=True)
class BridgePolicy:
    fixed: bool = False                     # the PX4 on the other side has the fix

    @classmethod
    def from_env(cls) -> BridgePolicy:
        return cls(fixed=os.environ.get(ENV_FIXED, "") in ("1", "true", "yes"))

    def allows(self, topic: Px4Topic) -> bool:
        return self.fixed or topic not in MISROUTED

    def require(self, topic: Px4Topic) -> None:
        if not self.allows(topic):
            raise BridgeBugError(
                f"{topic.name} is not sent: this PX4's zenoh module delivers it to the wrong uORB topic "
                f"(needs {FIX}; set {ENV_FIXED}=1 or BridgePolicy(fixed=True) for a fixed PX4)")
