"""ROS 2 name rules for nodes, namespaces and topics, and their Zenoh key."""
from __future__ import annotations

import re

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class InvalidNameError(ValueError):
    """A node, namespace or topic name that ROS 2 would refuse; the message says why."""


def validate_node_name(name: str) -> str:
    if not isinstance(name, str) or not _TOKEN.match(name):
        raise InvalidNameError(
            f"invalid node name {name!r}: use letters, digits and underscores, not starting with a digit")
    return name


def _tokens(path: str, what: str, original: str) -> list[str]:
    if path == "":
        return []
    parts = path.split("/")
    for part in parts:
        if part == "":
            raise InvalidNameError(f"invalid {what} {original!r}: empty token ('//' or a trailing '/')")
        if not _TOKEN.match(part):
            raise InvalidNameError(
                f"invalid {what} {original!r}: token {part!r} must be letters, digits, underscores, "
                "not starting with a digit")
    return parts


def normalize_namespace(namespace: str | None) -> str:
    """'' or '/uav1' or 'uav1/cam' -> 'uav1/cam' (no leading or trailing slash)."""
    if not namespace or namespace == "/":
        return ""
    ns = namespace[1:] if namespace.startswith("/") else namespace
    return "/".join(_tokens(ns, "namespace", namespace))


def resolve_topic(topic: str, namespace: str = "", node_name: str = "") -> str:
    """The Zenoh key of ``topic`` as seen from a node: ``t`` in ``uav1`` -> ``uav1/t``.

    ``/t`` is absolute (namespace ignored); ``~/t`` is private to the node (``ns/node/t``).
    """
    if not isinstance(topic, str) or not topic:
        raise InvalidNameError(f"invalid topic name {topic!r}: must be a non-empty string")
    if topic.startswith("~"):
        if not topic.startswith("~/") or not node_name:
            raise InvalidNameError(f"invalid topic name {topic!r}: private names are '~/name' inside a node")
        prefix = [p for p in (namespace, node_name) if p]
        rest = topic[2:]
    elif topic.startswith("/"):
        prefix, rest = [], topic[1:]
    else:
        prefix, rest = ([namespace] if namespace else []), topic
    if rest.endswith("/"):
        raise InvalidNameError(f"invalid topic name {topic!r}: must not end with '/'")
    return "/".join(prefix + _tokens(rest, "topic name", topic))
