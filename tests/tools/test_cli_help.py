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


def _choices(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def test_a_command_builds_only_its_own_part_and_parses_as_the_whole_tree_does() -> None:
    """A command line registers only its subcommand (a one-shot `topic list` does not import the apps and the
    doctor's plugins: ~0.3 s of CPU at every start); its parser is the whole tree's, and a name no single part
    registers (a plugin that adds several, a typo) gets the whole tree and its list of choices."""
    full = _choices(build_parser())
    lazy = {name: _choices(build_parser(name)) for name in full}
    assert set(lazy["topic"]) == {"topic"} and set(lazy["gcs"]) == {"gcs"} and set(lazy["companion"]) == {"companion"}
    for name, choices in lazy.items():
        assert name in choices
        assert choices[name].format_help() == full[name].format_help(), name
    assert set(_choices(build_parser("nosuch"))) == set(full)
