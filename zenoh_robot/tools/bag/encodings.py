"""How channels that are not JSON are written so that Foxglove, ``ros2 bag`` and rosbags decode them.

- Raw wire channels (``/_zr/raw/<topic>``, what ``bag play`` republishes): each envelope is one
  protobuf message ``zenoh_robot.RawEnvelope { bytes envelope = 1; }`` (message and schema encoding
  ``protobuf``, the schema a FileDescriptorSet, as Foxglove's "custom schema encodings" page asks), so
  Foxglove shows them instead of "unsupported encoding". The frame costs 2-4 bytes: a tag and the
  length as a varint before the envelope's bytes, untouched. The descriptor is written out by hand
  here (a dozen fields), so the logs extra needs no protobuf runtime.
- ROS 2 topics (a recorder on the ROS 2 wire): the CDR payload as it arrived (message encoding
  ``cdr``), the schema ``ros2msg``: the type's ``.msg`` text, then each type it uses after a line of
  80 ``=`` and ``MSG: pkg/Type``, as rosbag2 writes it (MCAP's well-known schema encodings).
"""
from __future__ import annotations

RAW_ENVELOPE_SCHEMA = "zenoh_robot.RawEnvelope"
PROTOBUF = "protobuf"
CDR = "cdr"
ROS2MSG = "ros2msg"
_SEPARATOR = "=" * 80


# -- protobuf, the few wire types used -----------------------------------------------------------
def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        if n:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _bytes_field(number: int, data: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(data)) + data


def _int_field(number: int, value: int) -> bytes:
    return _varint(number << 3) + _varint(value)


def _raw_envelope_descriptor() -> bytes:
    # descriptor.proto: FieldDescriptorProto name=1 number=3 label=4 (OPTIONAL=1) type=5 (BYTES=12)
    # json_name=10; DescriptorProto name=1 field=2; FileDescriptorProto name=1 package=2
    # message_type=4 syntax=12; FileDescriptorSet file=1.
    field = (_bytes_field(1, b"envelope") + _int_field(3, 1) + _int_field(4, 1) + _int_field(5, 12)
             + _bytes_field(10, b"envelope"))
    message = _bytes_field(1, b"RawEnvelope") + _bytes_field(2, field)
    file = (_bytes_field(1, b"zenoh_robot/raw_envelope.proto") + _bytes_field(2, b"zenoh_robot")
            + _bytes_field(4, message) + _bytes_field(12, b"proto3"))
    return _bytes_field(1, file)


RAW_ENVELOPE_DESCRIPTOR = _raw_envelope_descriptor()
_TAG = _varint(1 << 3 | 2)


def wrap_envelope(data: bytes) -> bytes:
    """The ``RawEnvelope`` message holding ``data``."""
    if not data:
        return b""            # proto3 writes no empty bytes field
    return _TAG + _varint(len(data)) + data


def unwrap_envelope(message: bytes | memoryview) -> bytes:
    """The envelope bytes of a ``RawEnvelope`` message; ValueError for anything else."""
    buf = bytes(message)
    if not buf:
        return b""            # proto3: an empty bytes field is not written at all
    if buf[:1] != _TAG:
        raise ValueError("not a zenoh_robot.RawEnvelope message (field 1, bytes)")
    length, shift, at = 0, 0, 1
    while True:
        if at >= len(buf) or shift > 63:
            raise ValueError("truncated RawEnvelope length")
        byte = buf[at]
        length |= (byte & 0x7F) << shift
        shift, at = shift + 7, at + 1
        if not byte & 0x80:
            break
    if at + length != len(buf):
        raise ValueError(f"RawEnvelope of {len(buf)} bytes says {length} bytes of envelope after {at}")
    return buf[at:]


# -- ros2msg ---------------------------------------------------------------------------------------
def ros2msg_schema(type_name: str) -> bytes:
    """The full ``ros2msg`` definition of ``pkg/msg/Type`` with every type it uses (needs the ros2 extra);
    KeyError for a type this process has no definition of."""
    from zenoh_robot.ros2 import dependencies, msg_definition, ros2_type

    ros2_type(type_name)      # an installed provider registers its package (px4_msgs) on first use
    parts = [msg_definition(type_name).rstrip("\n")]
    for dep in dependencies(type_name):
        pkg, _, short = dep.split("/")
        parts += [_SEPARATOR, f"MSG: {pkg}/{short}", msg_definition(dep).rstrip("\n")]
    return ("\n".join(parts) + "\n").encode()
