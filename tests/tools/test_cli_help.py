"""Every ``--help`` of the ``zenoh-robot`` command renders: argparse %-formats each help text, so a bare
``%`` in one (``cpu %)``, ``90 % loss``) crashed ``zenoh-robot --help`` for every user."""
from __future__ import annotations

import argparse

import pytest

from zenoh_robot.tools.cli.main import build_parser

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)


def _walk(parser: argparse.ArgumentParser, path: str) -> list[tuple[str, argparse.ArgumentParser]]:
    out = [(path, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out += _walk(sub, f"{path} {name}")
    return out


def test_every_help_renders() -> None:
    parsers = _walk(build_parser(), "zenoh-robot")
    assert len(parsers) > 40    # the library's commands and the apps' plugged-in ones
    for path, parser in parsers:
        text = parser.format_help()
        assert text.startswith("usage:"), path
