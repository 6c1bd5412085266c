"""Names a package exports, loaded on first use (PEP 562) instead of at ``import``.

``python -m px4_link.sim`` (and ``px4_zenoh.sim``) imports its packages before its ``__main__`` can catch
a Ctrl-C, and what they export pulls in pymavlink or Zenoh (0.3-0.5 s): a Ctrl-C in that window, as a
launch stopping early sends, printed a traceback. Lazily exported, the packages load in milliseconds and
the heavy imports run inside ``__main__``'s ``try``.
"""
from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, where: Mapping[str, tuple[str, ...]]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: ``where`` maps each submodule (``.link``) to the names it
    gives; a name is imported on first use and then kept in the package like an eager import's."""
    module_of = {name: module for module, names in where.items() for name in names}

    def __getattr__(name: str) -> Any:
        module = module_of.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__
