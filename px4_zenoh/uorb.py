"""px4_msgs types at run time, and their CDR as PX4's zenoh module writes and reads it.

Definitions come from this package's ``msg/`` (the types the backend uses, PX4 main 2026-03) or
from a PX4 tree's own ``msg/`` (``--px4-msgs``): PX4 computes the RIHS01 hashes in its keys from
its own ``.msg`` files at build time, so another PX4 version's types may differ; the backend then
learns the exact keys from PX4's tokens and names any mismatch (``topics.KeyBook``).

PX4 sends its buffer's capacity: the 4-byte header, the CDR body, then 0-31 bytes of leftover
memory, which strict CDR readers (rosbags) reject. Every uORB message is a fixed-size C struct,
so its CDR body has one length: the codec cuts the payload to it before decoding.

Threading: ``load_types`` takes the ROS 2 type registry's lock; codecs are stateless and shared.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from zenoh_robot.message import Message, type_support
from zenoh_robot.ros2 import cdr_codec, ros2_type
from zenoh_robot.ros2.types import parse_definition, register_definitions

BUNDLED = Path(__file__).with_name("msg")
PKG = "px4_msgs/msg/"


def msg_files(root: Path) -> dict[str, Path]:
    """``Type -> .msg`` under ``root``: this package's ``msg/`` or a PX4 tree's ``msg/`` (whose
    ``versioned/`` holds the current version of the versioned types; ``px4_msgs_old/`` is skipped)."""
    if not root.is_dir():
        raise FileNotFoundError(f"no px4_msgs definitions at {root}: give PX4's msg/ directory")
    found = {p.stem: p for p in sorted(root.glob("*.msg"))}
    found.update({p.stem: p for p in sorted((root / "versioned").glob("*.msg"))})
    if not found:
        raise FileNotFoundError(f"no .msg files in {root}")
    return found


def load_types(msg_dir: Path | None = None, names: Iterable[str] | None = None) -> dict[str, type[Message]]:
    """Register the px4_msgs definitions of ``msg_dir`` (default: the bundled ones) and return the
    message classes of ``names`` (short names, ``VehicleStatus``; default: every file's).

    Every definition is registered before any class is made, so nested types resolve in any order."""
    files = _register(msg_files(msg_dir or BUNDLED))
    wanted = list(files) if names is None else list(names)
    missing = [n for n in wanted if n not in files]
    if missing:
        raise KeyError(f"px4_msgs definitions missing in {msg_dir or BUNDLED}: {', '.join(missing)}")
    return {n: ros2_type(PKG + n) for n in wanted}


def register_bundled() -> None:
    """Register the bundled px4_msgs definitions (no classes made): the ``zenoh_robot.ros2_types``
    entry point ``px4_msgs``, through which ``zenoh-robot topic echo`` decodes PX4's ``/fmu`` topics."""
    _register(msg_files(BUNDLED))


def _register(files: dict[str, Path]) -> dict[str, Path]:
    defs: dict[str, Any] = {}
    for short, path in files.items():
        defs.update(parse_definition(path.read_text(encoding="utf-8"), PKG + short))
    register_definitions(defs)
    return files


@dataclass(frozen=True)
class UorbCodec:
    """One px4_msgs type's payload codec: message <-> ``00 01 00 00`` + XCDR1 LE body."""
    msg_type: type[Message]
    body_len: int          # the fixed CDR body length (bytes after the 4-byte header)

    @classmethod
    def of(cls, msg_type: type[Message]) -> UorbCodec:
        support = type_support(msg_type)
        empty = cdr_codec(msg_type).serialize(support.encode(msg_type()))
        return cls(msg_type, len(empty) - 4)

    @property
    def type_name(self) -> str:
        return type_support(self.msg_type).name

    @property
    def type_hash(self) -> str:
        return type_support(self.msg_type).hash

    def decode(self, payload: bytes | memoryview) -> Any:
        """The message in ``payload`` (trailing bytes after the body ignored); ValueError when it is
        shorter than the type or its header is not little-endian CDR."""
        view = memoryview(payload)
        if len(view) < 4 + self.body_len:
            raise ValueError(f"{self.type_name}: {len(view)} bytes, the type needs {4 + self.body_len}")
        if bytes(view[:2]) != b"\x00\x01":
            raise ValueError(f"{self.type_name}: not little-endian CDR (header {bytes(view[:4]).hex()})")
        body = cdr_codec(self.msg_type).deserialize(view[:4 + self.body_len])
        return type_support(self.msg_type).decode(body)

    def encode(self, msg: Any) -> bytes:
        return cdr_codec(self.msg_type).serialize(type_support(self.msg_type).encode(msg))
