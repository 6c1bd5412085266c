"""px4_link, px4_zenoh and their simulators' packages load their names on first use (px4_link/lazy.py).

`python -m px4_link.sim` imports its packages before its __main__ can catch a Ctrl-C; eager, they pulled in
pymavlink or Zenoh there (0.3-0.5 s), and a Ctrl-C in that window printed a traceback (issue #39).
"""
from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

PACKAGES = ["px4_link", "px4_link.sim", "px4_zenoh", "px4_zenoh.sim"]


@pytest.mark.fast
@pytest.mark.parametrize("name", PACKAGES)
def test_every_exported_name_loads_on_first_use(name: str) -> None:
    package = importlib.import_module(name)
    for export in package.__all__:
        value = getattr(package, export)
        assert vars(package)[export] is value, export     # kept, as an eager import's name is
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        _ = package.nothing_here


def test_importing_the_packages_loads_neither_mavlink_nor_zenoh() -> None:
    code = ("import sys, px4_link, px4_link.sim, px4_zenoh, px4_zenoh.sim; "
            "print(sorted(m for m in ('pymavlink', 'zenoh', 'zenoh_robot', 'numpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "[]", (out.stdout, out.stderr)
