"""The two interfaces a wire format implements: samples (:class:`WireFormat`) and the graph
(:class:`GraphFormat`).

A sample on the wire carries a header (type name and hash, publisher id, sequence number,
source stamp), a body and optional extra fields. The body is the type support's field values
(``TypeSupport.encode``: values in declaration order, nested messages as lists); a format
turns it into bytes and back, and chooses the Zenoh key a topic's samples travel on. The
library's entities never touch bytes or keys themselves: a Node's format (``Node(wire=...)``)
reaches them through their ``EntityContext``.

Threading: a format object is shared by every entity of every node that uses it and must be
stateless (or thread safe). An encoder belongs to one publisher, which serialises its calls
under its lock; a decoder is called on the executor, one sample at a time per subscription.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

if TYPE_CHECKING:
    from ..graph import NodeInfo, TopicEndpointInfo
    from ..message import TypeSupport

# (type_name, type_hash, publisher_id, seq, stamp_ns, body, extra): a decoder's result as a plain
# tuple, so the receive path makes no object per sample; WireSample names the same fields.
Header = tuple[str, str, int, int, int, Any, dict[str, Any]]
Decoder = Callable[[bytes, "bytes | None"], Header]


class WireSample(NamedTuple):
    """One sample's header, body and extra fields (``WireSample._make(decoder(payload, None))``)."""
    type_name: str
    type_hash: str
    publisher_id: int
    seq: int
    stamp_ns: int
    body: Any
    extra: dict[str, Any]


class SampleEncoder(Protocol):
    """One publisher's encoder (fixed type and publisher id). Not thread safe: the publisher
    serialises calls."""

    def pack(self, seq: int, stamp_ns: int, body: Any, extra: dict[str, Any] | None = None) -> bytes:
        """The payload of one sample. ``extra`` is None or empty unless the format ``carries_extra``."""
        ...

    def attachment(self, seq: int, stamp_ns: int) -> bytes | None:
        """The Zenoh attachment of that sample; called only when the format ``uses_attachment``."""
        ...


class GraphFormat(Protocol):
    """How nodes and endpoints are announced as liveliness tokens, and read back."""

    @property
    def selector(self) -> str:
        """A key expression matching every token of this format (and no data key)."""
        ...

    def node_token(self, info: NodeInfo) -> str: ...

    def node_selector(self, namespace: str, node_name: str) -> str:
        """A key expression matching the node tokens of ``namespace``/``node_name`` in any session."""
        ...

    def endpoint_token(self, info: TopicEndpointInfo) -> str: ...

    def parse_token(self, key: str) -> NodeInfo | TopicEndpointInfo:
        """What a token key announces; ValueError for a key this format did not make."""
        ...


class WireFormat(Protocol):
    """Where a message becomes bytes and a key, and back (see the module doc).

    ``carries_extra``: whether samples carry the extra map, which the redundancy history and
    the repeat marker ride in. A publisher whose QoS asks for ``redundancy`` or ``repeat`` on
    a format without it is refused when it is created (ValueError).
    ``uses_attachment``: whether samples have a Zenoh attachment (the publisher asks the
    encoder for one, the subscription hands the received one to the decoder); without it the
    attachment is never read.
    """

    name: str
    carries_extra: bool
    uses_attachment: bool
    graph: GraphFormat

    def data_key(self, topic_key: str, type_support: TypeSupport | None) -> str:
        """The key expression of ``topic_key`` (a resolved topic, ``uav1/setpoint``) for one type
        (None: every type, for a raw subscription)."""
        ...

    def encoder(self, type_support: TypeSupport, publisher_id: int) -> SampleEncoder: ...

    def decoder(self, type_support: TypeSupport | None) -> Decoder:
        """``decode(payload, attachment) -> Header`` for samples of one type (None: any type; a format
        that cannot tell types apart raises ValueError here). ``decode`` raises
        :class:`~zenoh_robot.wire.MalformedSample` for anything it does not accept, and nothing else."""
        ...
