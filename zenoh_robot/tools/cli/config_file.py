"""``--config-file FILE``: a program's flags from a YAML file, every flag on the command line winning.

A drone's settings live in one file that the unit at boot and a person at a terminal share
(``companion --config-file /etc/zenoh-robot/uav1.yaml --duration 30``). Each key is a flag's long name
(``sensor-rate`` or ``sensor_rate``); a value is what the flag takes (a list where the flag repeats,
``true`` for a switch). The file's values become the subcommand's defaults and the command line is parsed
again, so a flag given there wins wherever it stands. A key no flag has, or a value the flag would
refuse, is one line naming the file, the key and what is accepted.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml


class ConfigFileError(ValueError):
    """A config file that cannot be used; the message names the file and the key."""


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            sub: argparse.ArgumentParser = action.choices[command]
            return sub
    raise ConfigFileError(f"{command} takes no --config-file")


def _settings(sub: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """Each flag's long names (dashes and underscores alike) -> its action."""
    names: dict[str, argparse.Action] = {}
    for action in sub._actions:
        if action.dest in ("help", "config_file", "func") or not action.option_strings:
            continue
        for opt in action.option_strings:
            if opt.startswith("--"):
                names[opt[2:]] = names[opt[2:].replace("-", "_")] = action
        names.setdefault(action.dest, action)
    return names


def _value(path: Path, key: str, action: argparse.Action, value: Any) -> Any:
    flag = action.option_strings[-1]
    if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
        if not isinstance(value, bool):
            raise ConfigFileError(f"{path}: {key}: {flag} is a switch, give true or false, got {value!r}")
        return value if isinstance(action, argparse._StoreTrueAction) else not value
    if isinstance(action, argparse._AppendAction) or action.nargs in ("*", "+"):
        items = value if isinstance(value, list) else [value]
        return [_one(path, key, action, flag, v) for v in items]
    if isinstance(value, (list, dict)):
        raise ConfigFileError(f"{path}: {key}: {flag} takes one value, got {value!r}")
    return _one(path, key, action, flag, value)


def _one(path: Path, key: str, action: argparse.Action, flag: str, value: Any) -> Any:
    if value is None or isinstance(value, (list, dict)):
        raise ConfigFileError(f"{path}: {key}: {flag} takes a value, got {value!r}")
    text = value if isinstance(value, str) else str(value).lower() if isinstance(value, bool) else str(value)
    try:   # as the command line would read it: its type, then its choices
        converted = action.type(text) if callable(action.type) else text
    except (TypeError, ValueError, argparse.ArgumentTypeError) as exc:
        raise ConfigFileError(f"{path}: {key}: {flag} does not take {value!r} ({exc})") from None
    if action.choices is not None and converted not in action.choices:
        choices = ", ".join(map(str, action.choices))
        raise ConfigFileError(f"{path}: {key}: {value!r} is not one of {choices}")
    return converted


def apply_config_file(parser: argparse.ArgumentParser, args: argparse.Namespace,
                      argv: list[str] | None) -> argparse.Namespace:
    """``args`` again, parsed with the file's settings as the subcommand's defaults."""
    path = Path(args.config_file)
    try:
        loaded = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigFileError(f"--config-file {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigFileError(f"--config-file {path}: not YAML: {' '.join(str(exc).split())}") from None
    if loaded is None:
        return args
    if not isinstance(loaded, dict):
        raise ConfigFileError(f"--config-file {path}: a mapping of flag names to values, got {type(loaded).__name__}")
    sub = _subparser(parser, args.command)
    settings = _settings(sub)
    defaults: dict[str, Any] = {}
    for key, value in loaded.items():
        action = settings.get(str(key))
        if action is None:
            known = sorted(k for k in settings if "_" not in k or k.replace("_", "-") not in settings)
            raise ConfigFileError(f"--config-file {path}: no setting {key!r}; the flags' long names are: "
                                  f"{', '.join(known)}")
        defaults[action.dest] = _value(path, str(key), action, value)
    sub.set_defaults(**defaults)
    return parser.parse_args(argv)
