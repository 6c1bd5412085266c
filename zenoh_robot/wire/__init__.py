"""Wire formats: where a message becomes bytes and a Zenoh key, and back, and how the graph is
announced. ``ENVELOPE`` (zenoh-robot's msgpack envelope) is the default; another format (e.g.
ROS 2's rmw_zenoh) implements :class:`WireFormat` and :class:`GraphFormat` and is chosen per node
with ``Node(..., wire=fmt)``. Nodes of different formats do not see each other's samples or graph.
See docs/guide.md, "Wire formats".
"""
from .._wire.envelope import MalformedSample
from .envelope_format import ENVELOPE, EnvelopeWireFormat
from .format import Decoder, GraphFormat, Header, SampleEncoder, WireFormat, WireSample

__all__ = ["ENVELOPE", "Decoder", "EnvelopeWireFormat", "GraphFormat", "Header", "MalformedSample",
           "SampleEncoder", "WireFormat", "WireSample"]
