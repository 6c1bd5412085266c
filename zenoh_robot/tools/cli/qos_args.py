"""QoS on the command line, as ``ros2 topic pub/echo`` take it: one module for every command.

``--qos-profile NAME`` (or ``--qos FILE.yaml:PROFILE``) is the base; each ``--qos-POLICY``
flag then overrides one policy. Durations are seconds (``--qos-deadline 1.0``; ``infinite``
or 0 for none). With no flag at all, :func:`qos_from_args` returns None and the command
chooses (echo adapts to the publishers, pub uses ``system_default``).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .main import CliError

if TYPE_CHECKING:
    from zenoh_robot.qos import QoSProfile

# flag suffix -> QoSProfile field
POLICY_FLAGS = {"reliability": "reliability", "durability": "durability", "history": "history",
                "depth": "depth", "deadline": "deadline", "lifespan": "lifespan", "liveliness": "liveliness",
                "liveliness-lease-duration": "liveliness_lease_duration"}
_CHOICES = {"reliability": ("reliable", "best_effort", "system_default"),
            "durability": ("volatile", "transient_local", "system_default"),
            "history": ("keep_last", "keep_all", "system_default"),
            "liveliness": ("automatic", "manual_by_topic", "system_default")}


def add_qos_args(parser: argparse.ArgumentParser, default_profile: str | None = None) -> None:
    g = parser.add_argument_group("QoS (each --qos-POLICY overrides the profile's value)")
    g.add_argument("--qos-profile", metavar="NAME",
                   help="base QoS preset: system_default, sensor_data, setpoint, control, ..."
                        + (f" (default {default_profile})" if default_profile else ""))
    g.add_argument("--qos", dest="qos_file", metavar="FILE.yaml[:PROFILE]",
                   help="base QoS from a YAML file of profiles (PROFILE needed when it holds several)")
    for flag, field in POLICY_FLAGS.items():
        kind = "seconds" if field in ("deadline", "lifespan", "liveliness_lease_duration") else None
        choices = _CHOICES.get(flag)
        g.add_argument(f"--qos-{flag}", dest=f"qos_{field}", metavar="S" if kind else None,
                       type=int if field == "depth" else str, choices=choices,
                       help=f"{field.replace('_', ' ')}" + (" in seconds ('infinite' for none)" if kind else ""))
    parser.set_defaults(_qos_default_profile=default_profile)


def _from_file(spec: str) -> "QoSProfile":
    from zenoh_robot.qos import QoSError, load_qos

    path, sep, name = spec.rpartition(":")
    if not sep or not path or "/" in name:   # no ':PROFILE' (a ':' may be a Windows drive, or in a dir)
        path, name = spec, ""
    if not Path(path).is_file():
        raise CliError(f"--qos: no such file {path!r}")
    try:
        profiles = load_qos(path)
    except QoSError as exc:
        raise CliError(f"--qos: {exc}") from None
    if not name:
        if len(profiles) != 1:
            raise CliError(f"--qos: {path} holds {len(profiles)} profiles; choose one: "
                           f"{path}:{'|'.join(sorted(profiles))}")
        return next(iter(profiles.values()))
    if name not in profiles:
        raise CliError(f"--qos: {path} has no profile {name!r}; profiles: {', '.join(sorted(profiles))}")
    return profiles[name]


def explicit_qos(args: argparse.Namespace) -> bool:
    return bool(getattr(args, "qos_profile", None) or getattr(args, "qos_file", None)
                or any(getattr(args, f"qos_{f}", None) is not None for f in POLICY_FLAGS.values()))


def qos_from_args(args: argparse.Namespace) -> "QoSProfile | None":
    """The profile the flags describe, None when none was given (and no default profile)."""
    from zenoh_robot.qos import QoSError, QoSProfile, preset

    default = getattr(args, "_qos_default_profile", None)
    if not explicit_qos(args) and default is None:
        return None
    if args.qos_profile and args.qos_file:
        raise CliError("give --qos-profile or --qos FILE, not both")
    name: str | None = args.qos_profile or default
    try:
        if args.qos_file:
            base = _from_file(args.qos_file)
        elif name is not None:
            base = preset(name)
        else:   # echo adapts its QoS to the publishers only with no flag at all: a lone flag has no base
            raise CliError("a --qos-POLICY flag needs a base: give --qos-profile NAME or --qos FILE")
    except QoSError as exc:
        raise CliError(str(exc)) from None
    overrides: dict[str, Any] = {}
    for field in POLICY_FLAGS.values():
        value = getattr(args, f"qos_{field}", None)
        if value is None or value == "system_default":
            continue
        overrides[field] = value
    if not overrides:
        return base
    if overrides.get("history") == "keep_all" and "depth" not in overrides:
        overrides["depth"] = 0
    if "depth" in overrides and overrides["depth"] < 0:
        raise CliError(f"--qos-depth must be >= 0, got {overrides['depth']}")
    try:
        return QoSProfile.from_dict(overrides, base)
    except (QoSError, ValueError, TypeError) as exc:
        raise CliError(f"QoS: {exc}") from None
