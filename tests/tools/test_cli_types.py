"""A command knows every message type by name without building the whole command tree: the CLI once
learnt the applications' and the image transport's types as a side effect of importing every subcommand,
and lost them when a command line came to register only its own (`topic hz` of a sliced image stream
counted slices, `bag record` wrote schemaless channels)."""
from __future__ import annotations

import json
import subprocess
import sys

NAMES = r"""
import importlib, json, pkgutil, sys
from zenoh_robot.message import _REGISTRY
if sys.argv[1] == "cli":
    from zenoh_robot.tools.cli.common import register_message_types
    register_message_types()
else:   # every module of the library and of the drone contract imported
    import drone_contract, zenoh_robot
    for pkg in (zenoh_robot, drone_contract):
        for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            if not m.name.endswith("__main__"):
                importlib.import_module(m.name)
print(json.dumps(sorted(k for k in _REGISTRY if "/" in k)))
"""


def _names(mode: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", NAMES, mode], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout))


def test_a_command_registers_every_message_type_the_packages_define() -> None:
    everything = _names("all")
    assert {"zenoh_robot/ImageSlice", "zenoh_robot/ImageShare", "zenoh_robot/VehicleState"} <= everything
    assert _names("cli") == everything
