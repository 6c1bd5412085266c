"""The wire format seam (``zenoh_robot.wire``): a second format plugs in without touching Publisher,
Subscription or Graph, and the envelope's bytes stay what they were.

The toy format here is JSON: the body and type in the payload, the sequence number, stamp and
publisher id in a 24-byte attachment (as rmw_zenoh carries them), one key per type under ``jz/``,
and graph tokens of its own under ``@jz/lv``.
"""
from __future__ import annotations

import json
import struct
import time
from typing import Any

import pytest
from conftest import linked_configs, wait_for

from zenoh_robot import Node, QoSProfile, envelope
from zenoh_robot.graph import EndpointType, NodeInfo, TopicEndpointInfo, decode_qos, encode_qos
from zenoh_robot.message import TypeSupport, type_support
from zenoh_robot.msgs import Setpoint, String
from zenoh_robot.wire import ENVELOPE, Header, MalformedSample, WireFormat, WireSample

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

_ATTACHMENT = struct.Struct("<qqq")     # seq, stamp_ns, publisher id


def _mangle(text: str) -> str:
    return text.replace("/", "%") if text else "%"


def _unmangle(text: str) -> str:
    return "" if text == "%" else text.replace("%", "/")


class JsonGraph:
    selector = "@jz/lv/**"

    def node_token(self, info: NodeInfo) -> str:
        return f"@jz/lv/N/{info.zid}/{_mangle(info.namespace)}/{info.name}"

    def node_selector(self, namespace: str, node_name: str) -> str:
        return f"@jz/lv/N/*/{_mangle('/' + namespace)}/{node_name}"

    def endpoint_token(self, info: TopicEndpointInfo) -> str:
        kind = "P" if info.endpoint_type is EndpointType.PUBLISHER else "S"
        return "/".join(["@jz/lv", kind, info.zid, str(info.endpoint_gid), _mangle(info.node_namespace),
                         info.node_name, _mangle(info.topic_name), _mangle(info.topic_type), info.topic_type_hash,
                         encode_qos(info.qos_profile)])

    def parse_token(self, key: str) -> NodeInfo | TopicEndpointInfo:
        parts = key.split("/")
        if parts[:2] != ["@jz", "lv"]:
            raise ValueError(key)
        if parts[2] == "N" and len(parts) == 6:
            return NodeInfo(parts[5], _unmangle(parts[4]), parts[3])
        if parts[2] not in ("P", "S") or len(parts) != 11:
            raise ValueError(key)
        _, _, kind, zid, gid, ns, node, topic, type_name, type_hash, qos = parts
        return TopicEndpointInfo(node, _unmangle(ns), _unmangle(topic), _unmangle(type_name), type_hash,
                                 EndpointType.PUBLISHER if kind == "P" else EndpointType.SUBSCRIPTION, int(gid),
                                 decode_qos(qos), zid)


class JsonEncoder:
    def __init__(self, ts: TypeSupport, publisher_id: int) -> None:
        self._head = {"type": ts.name, "hash": ts.hash}
        self._publisher_id = publisher_id

    def pack(self, seq: int, stamp_ns: int, body: Any, extra: dict[str, Any] | None = None) -> bytes:
        if extra:
            raise ValueError("the JSON format carries no extra fields")
        return json.dumps({**self._head, "body": body}).encode()

    def attachment(self, seq: int, stamp_ns: int) -> bytes:
        return _ATTACHMENT.pack(seq, stamp_ns, self._publisher_id)


class JsonWireFormat:
    name = "json"
    carries_extra = False
    uses_attachment = True
    graph = JsonGraph()

    def data_key(self, topic_key: str, type_support: TypeSupport | None) -> str:
        return f"jz/{topic_key}/{_mangle(type_support.name) if type_support is not None else '*'}"

    def encoder(self, type_support: TypeSupport, publisher_id: int) -> JsonEncoder:
        return JsonEncoder(type_support, publisher_id)

    def decoder(self, type_support: TypeSupport | None) -> Any:
        def decode(payload: bytes, attachment: bytes | None) -> Header:
            try:
                obj = json.loads(payload)
                seq, stamp, pub_id = _ATTACHMENT.unpack(attachment or b"")
                return obj["type"], obj["hash"], pub_id, seq, stamp, obj["body"], {}
            except (ValueError, KeyError, TypeError, struct.error) as exc:
                raise MalformedSample(f"not a JSON sample: {type(exc).__name__}") from None
        return decode


JSON: WireFormat = JsonWireFormat()


@pytest.fixture
def json_pair(ns: str):
    """(talker, listener), both speaking JSON."""
    listen, connect = linked_configs()
    with Node("listener", namespace=ns, config=listen, wire=JSON) as b, \
            Node("talker", namespace=ns, config=connect, wire=JSON) as a:
        assert wait_for(lambda: any(link.zid == b.session.zid() for link in a.session.info.links()), 10.0)
        yield a, b


def test_a_second_format_carries_samples_between_two_nodes(json_pair, ns: str) -> None:
    a, b = json_pair
    got: list[tuple[Setpoint, Any]] = []
    keys: list[str] = []
    b.session.declare_subscriber("jz/**", lambda s: keys.append(str(s.key_expr)))
    sub = b.create_subscription(Setpoint, "sp", lambda m, info: got.append((m, info)), 10)
    pub = a.create_publisher(Setpoint, "sp", 10)
    assert wait_for(lambda: pub.get_subscription_count() == 1 and sub.get_publisher_count() == 1)
    sent = [pub.publish(Setpoint(x=float(i), y=2.0)) for i in range(5)]
    assert b.spin_until(lambda: len(got) == 5, timeout=5.0)
    assert [m.x for m, _ in got] == [0.0, 1.0, 2.0, 3.0, 4.0]
    # Sequence number, stamp and publisher id came in the attachment.
    assert [(i.seq, i.source_stamp_ns, i.publisher_id) for _, i in got] == \
        [(s.seq, s.stamp_ns, pub.publisher_id) for s in sent]
    assert got[0][1].type_name == type_support(Setpoint).name
    # The plain subscriber's callback runs on Zenoh's thread, not the spin: give it its own wait.
    assert wait_for(lambda: len(keys) == 5), keys
    assert keys[0] == f"jz/{ns}/sp/{_mangle(type_support(Setpoint).name)}" == pub.data_key
    assert sub.counters.malformed == 0 and sub.counters.lost == 0


def test_a_second_format_has_its_own_graph(json_pair, ns: str) -> None:
    a, b = json_pair
    a.create_publisher(Setpoint, "sp", 10)
    b.create_subscription(String, "chat", lambda m: None, 10)
    assert wait_for(lambda: len(b.get_publishers_info_by_topic("sp")) == 1
                    and len(a.get_subscriptions_info_by_topic("chat")) == 1)
    info = b.get_publishers_info_by_topic("sp")[0]
    assert (info.node_name, info.node_namespace, info.topic_type, info.endpoint_type) == \
        ("talker", f"/{ns}", type_support(Setpoint).name, EndpointType.PUBLISHER)
    assert (f"/{ns}/sp", [type_support(Setpoint).name]) in b.get_topic_names_and_types()
    assert wait_for(lambda: {("listener", f"/{ns}"), ("talker", f"/{ns}")}
                    <= set(a.get_node_names_and_namespaces()))
    # The tokens are the format's own.
    tokens = [str(r.ok.key_expr) for r in a.session.liveliness().get("@jz/lv/**", timeout=1.0) if r.ok]
    assert any(t.startswith("@jz/lv/P/") for t in tokens) and any(t.startswith("@jz/lv/N/") for t in tokens)


def test_nodes_of_different_formats_neither_hear_nor_see_each_other(ns: str) -> None:
    listen, connect = linked_configs()
    with Node("listener", namespace=ns, config=listen) as env_node, \
            Node("talker", namespace=ns, config=connect, wire=JSON) as json_node:
        assert wait_for(lambda: any(link.zid == env_node.session.zid() for link in json_node.session.info.links()),
                        10.0)
        on_wire: list[str] = []
        env_node.session.declare_subscriber("jz/**", lambda s: on_wire.append(str(s.key_expr)))
        env_got: list[Any] = []
        json_got: list[Any] = []
        # "a": JSON talks, the envelope node listens; "b": the other way round.
        env_sub = env_node.create_subscription(Setpoint, "a", env_got.append, 10)
        json_sub = json_node.create_subscription(Setpoint, "b", json_got.append, 10)
        json_pub = json_node.create_publisher(Setpoint, "a", 10)
        env_pub = env_node.create_publisher(Setpoint, "b", 10)
        time.sleep(0.5)
        for i in range(5):
            json_pub.publish(Setpoint(x=float(i)))
            env_pub.publish(Setpoint(x=float(i)))
        assert wait_for(lambda: len(on_wire) >= 5)    # the JSON samples did reach the envelope node's session
        env_node.spin_until(lambda: False, timeout=0.5)
        json_node.spin_until(lambda: False, timeout=0.5)
        assert env_got == [] and json_got == []
        assert env_sub.counters.received == json_sub.counters.received == 0
        assert env_pub.get_subscription_count() == 0 and json_pub.get_subscription_count() == 0
        # Neither graph lists the other format's endpoints or nodes.
        assert env_node.get_publishers_info_by_topic("a") == [] == json_node.get_publishers_info_by_topic("b")
        assert json_node.get_subscriptions_info_by_topic("a") == [] == env_node.get_subscriptions_info_by_topic("b")
        assert "talker" not in env_node.get_node_names()
        assert "listener" not in json_node.get_node_names()


def test_bytes_of_another_format_on_the_key_are_malformed(json_pair, ns: str) -> None:
    a, b = json_pair
    sub = b.create_subscription(Setpoint, "sp", lambda m: None, 10)
    time.sleep(0.3)
    ts = type_support(Setpoint)
    a.session.put(sub.data_key, envelope.pack(ts.name, ts.hash, 1, 1, time.time_ns(), ts.encode(Setpoint())))
    assert b.spin_until(lambda: sub.counters.malformed == 1, timeout=5.0)
    assert sub.counters.delivered == 0


def test_a_format_without_extra_fields_refuses_redundancy_and_repeats(json_pair) -> None:
    a, _ = json_pair
    for profile in (QoSProfile(depth=10, redundancy=2), QoSProfile(depth=10, repeat=2)):
        with pytest.raises(ValueError, match="json wire format cannot carry redundancy or repeats"):
            a.create_publisher(Setpoint, "sp", profile)
    assert a.publishers == []


def test_the_envelope_format_sends_the_envelope_bytes(ns: str) -> None:
    listen, connect = linked_configs()
    with Node("listener", namespace=ns, config=listen) as b, Node("talker", namespace=ns, config=connect) as a:
        assert a.wire is ENVELOPE
        raw: list[bytes] = []
        b.session.declare_subscriber(f"{ns}/sp", lambda s: raw.append(s.payload.to_bytes()))
        pub = a.create_publisher(Setpoint, "sp", 10)
        assert pub.data_key == pub.key == f"{ns}/sp"
        time.sleep(0.5)
        msg = Setpoint(x=1.5, y=-2.0, z=3.25)
        sent = [pub.publish(msg) for _ in range(3)]
        assert wait_for(lambda: len(raw) == 3)
        ts = type_support(Setpoint)
        assert raw == [envelope.pack(ts.name, ts.hash, pub.publisher_id, s.seq, s.stamp_ns, ts.encode(msg))
                       for s in sent]
        # The one-sample helpers tools use are the same bytes, both ways.
        sample = ENVELOPE.unpack(raw[0])
        assert sample._replace(body=None) == WireSample(ts.name, ts.hash, pub.publisher_id, sent[0].seq,
                                                        sent[0].stamp_ns, None, {})
        assert ts.decode(sample.body) == msg
        assert ENVELOPE.pack(sample) == raw[0]
        with pytest.raises(MalformedSample):
            ENVELOPE.unpack(b"\x00garbage")


def test_a_raw_subscription_of_any_type_works_through_the_format(json_pair) -> None:
    a, b = json_pair
    got: list[Any] = []
    sub = b.create_subscription(None, "any", lambda raw, info: got.append((raw, info)), 10, raw=True)
    pubs = [a.create_publisher(Setpoint, "any", 10), a.create_publisher(String, "any", 10)]
    assert wait_for(lambda: sub.get_publisher_count() == 2)
    # Matched on the graph is not yet routed: publish again until one of each type has arrived.
    names = {type_support(Setpoint).name, type_support(String).name}
    deadline = time.monotonic() + 10.0
    while {raw.type_name for raw, _ in got} != names and time.monotonic() < deadline:
        pubs[0].publish(Setpoint(x=2.0))
        pubs[1].publish(String(data="hi"))
        b.spin_until(lambda: {raw.type_name for raw, _ in got} == names, timeout=0.3)
    assert {raw.type_name for raw, _ in got} == names, got
    by_type = {raw.type_name: (raw, info) for raw, info in got}
    assert type_support(String).decode(by_type[type_support(String).name][0].fields) == String(data="hi")
    assert by_type[type_support(Setpoint).name][1].publisher_id == pubs[0].publisher_id
    assert json.loads(by_type[type_support(String).name][0].data)["body"] == ["hi"]
