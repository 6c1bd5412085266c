"""Wire formats: where a message becomes bytes and a Zenoh key, and back, and how the graph is
announced. ``ENVELOPE`` (zenoh-robot's msgpack envelope) is the default; ``ros2_wire(domain_id)``
is ROS 2's (rmw_zenoh's: CDR, ``@ros2_lv`` tokens; its types come from ``zenoh_robot.ros2``);
``sealed(fmt, keyring)`` puts an AEAD tag on every sample of another format (docs/security.md).
A format implements :class:`WireFormat` and :class:`GraphFormat` and is chosen per node with
``Node(..., wire=fmt)``. Nodes of different formats do not see each other's samples or graph.
See docs/guide.md, "Wire formats", and docs/ros2.md.
"""
from ..envelope import MalformedSample
from .envelope_format import ENVELOPE, EnvelopeWireFormat
from .format import Decoder, GraphFormat, Header, SampleEncoder, WireFormat, WireSample
from .ros2 import Ros2WireFormat, ros2_wire
from .sealed import DuplicateSample, SealCounters, SealedWireFormat, sealed

__all__ = ["ENVELOPE", "Decoder", "DuplicateSample", "EnvelopeWireFormat", "GraphFormat", "Header", "MalformedSample",
           "Ros2WireFormat", "SampleEncoder", "SealCounters", "SealedWireFormat", "WireFormat", "WireSample",
           "ros2_wire", "sealed"]
