"""The envelope, zenoh-robot's own wire format and the default one: a msgpack array per sample
on the topic's own key (``zenoh_robot/envelope.py`` has the layout), and the ``@zr/lv`` graph tokens
(``graph.py``). Its samples carry the extra map (redundancy, repeats) and no attachment."""
from __future__ import annotations

from typing import TYPE_CHECKING

from .. import envelope
from ..graph import ZR_GRAPH
from .format import Decoder, GraphFormat, WireSample

if TYPE_CHECKING:
    from ..message import TypeSupport


class EnvelopeWireFormat:
    """The :class:`~zenoh_robot.wire.WireFormat` of the envelope (use the instance ``ENVELOPE``)."""

    name = "envelope"
    carries_extra = True
    uses_attachment = False
    graph: GraphFormat = ZR_GRAPH

    def data_key(self, topic_key: str, type_support: TypeSupport | None) -> str:
        return topic_key     # every type on one key: the envelope names its type

    def encoder(self, type_support: TypeSupport, publisher_id: int) -> envelope.EnvelopePacker:
        return envelope.EnvelopePacker(type_support.name, type_support.hash, publisher_id)

    def decoder(self, type_support: TypeSupport | None) -> Decoder:
        return envelope.unpack_fields     # itself: no call more per sample

    # -- one sample at a time (tools: replay, statistics; services) ---------------------------
    def unpack(self, payload: bytes | memoryview) -> WireSample:
        """The sample in ``payload``; MalformedSample for anything else."""
        return WireSample._make(envelope.unpack_fields(payload))

    def pack(self, sample: WireSample) -> bytes:
        """The payload of ``sample``: the bytes a publisher of that type and id would send."""
        return envelope.pack(sample.type_name, sample.type_hash, sample.publisher_id, sample.seq, sample.stamp_ns,
                             sample.body, sample.extra)

    def __repr__(self) -> str:
        return "ENVELOPE"


ENVELOPE = EnvelopeWireFormat()
"""The default wire format (``Node(wire=ENVELOPE)``)."""

