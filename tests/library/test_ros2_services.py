"""Services on rmw_zenoh's wire, against an independent implementation (zenoh-ros2-sdk, in its own
process) through a Zenoh router, as rmw_zenoh nodes meet: a call each way, the graph's SS/SC tokens,
and byte-level checks against rmw_zenoh's documented key, attachment and hash.

zenoh-ros2-sdk would fetch .srv files from GitHub; the peer scripts hand it the definitions, so no
network is needed. Before this change services spoke only the envelope on ``@srv/...``: every call
here went unanswered.
"""
from __future__ import annotations

import contextlib
import logging
import struct
import threading
import time

import pytest
from conftest import fresh_domain, kill_process, python_proc, wait_for
from ros2_peer import router as ros2_router

from zenoh_robot import Node
from zenoh_robot.ros2 import ros2_service_type
from zenoh_robot.services import ServiceError, parse_service_token, ros2_services, service_data_key
from zenoh_robot.session_config import SessionConfig
from zenoh_robot.wire import MalformedSample
from zenoh_robot.wire.ros2 import LegacyAttachment, pack_attachment, ros2_wire, unpack_attachment

ADD = "example_interfaces/srv/AddTwoInts"
ADD_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"   # rmw_zenoh's docs

SDK_SERVER = r"""
import sys, time
from zenoh_ros2_sdk import ROS2ServiceServer
port, domain, name = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]

def add(req):
    return server.response_msg_class(sum=req.a + req.b)

server = ROS2ServiceServer(name, "example_interfaces/srv/AddTwoInts", callback=add,
                           request_definition="int64 a\nint64 b", response_definition="int64 sum",
                           node_name="sdk_adder", domain_id=domain, router_port=port)
print("ready", server.keyexpr, flush=True)
sys.stdin.readline()
"""

SDK_CLIENT = r"""
import sys, time
from zenoh_ros2_sdk import ROS2ServiceClient
port, domain, name = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
client = ROS2ServiceClient(name, "std_srvs/srv/SetBool", request_definition="bool data",
                           response_definition="bool success\nstring message", node_name="sdk_caller",
                           domain_id=domain, router_port=port, timeout=5.0)
print("key", client.keyexpr, flush=True)
for _ in range(40):          # until the server is discovered through the router
    resp = client.call(data=True)
    if resp is not None:
        print("reply", resp.success, resp.message, flush=True)
        break
    time.sleep(0.25)
else:
    print("no reply", flush=True)
"""


@pytest.fixture
def router():
    with ros2_router() as port:
        yield port


def ros2_node(name: str, port: int, domain: int) -> Node:
    # As rmw_zenoh's sessions: a peer that connects to the router, listens and gossips (rmw_zenoh #929).
    config = SessionConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"],
                           multicast_scouting=False)
    return Node(name, config=config, wire=ros2_wire(domain))


def domain_id() -> int:
    return fresh_domain()     # parallel or repeated runs never meet


def read_line(proc, prefix: str, timeout: float = 30.0) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        if line.startswith(prefix):
            return line.strip()
    raise AssertionError(f"no {prefix!r} line from the peer; stderr: {proc.stderr.read()[-2000:]}")


# -- byte level: rmw_zenoh's documented forms ------------------------------------------------------
def test_service_key_and_hash_are_rmw_zenohs():
    srv = ros2_service_type(ADD)
    assert srv.hash == ADD_HASH
    assert srv.dds_name == "example_interfaces::srv::dds_::AddTwoInts_"     # the Request_ suffix cut
    assert service_data_key(2, "/add_two_ints", srv) == \
        f"2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_HASH}"
    # The same hash as the independent implementation computes from the same definitions.
    from zenoh_ros2_sdk.utils import compute_service_type_hash
    assert compute_service_type_hash("std_srvs/srv/SetBool", "bool data", "bool success\nstring message") == \
        ros2_service_type("std_srvs/srv/SetBool").hash


def test_request_and_response_cdr_bytes():
    srv = ros2_service_type(ADD)
    data = srv.encode_request(srv.request(a=2, b=3))
    assert data == b"\x00\x01\x00\x00" + struct.pack("<qq", 2, 3)
    assert srv.decode_response(b"\x00\x01\x00\x00" + struct.pack("<q", 5)) == srv.response(sum=5)


def test_attachment_layout_and_legacy_detected():
    gid = bytes(range(16))
    att = pack_attachment(7, 1_700_000_000_000_000_000, gid)
    assert len(att) == 33 and att[16] == 16
    assert att[:16] == struct.pack("<qq", 7, 1_700_000_000_000_000_000)
    assert unpack_attachment(att) == (7, 1_700_000_000_000_000_000, gid)
    # Jazzy <= 0.2.3 labelled its fields (zenoh's serializer: length-prefixed names and values).
    legacy = b"\x0fsequence_number\x08" + struct.pack("<q", 7) + b"\x10source_timestamp\x08" + bytes(8) \
        + b"\x0asource_gid\x10" + gid
    with pytest.raises(LegacyAttachment, match="0.2.3"):
        unpack_attachment(legacy)
    with pytest.raises(MalformedSample) as exc:
        unpack_attachment(b"\x01\x02")
    assert not isinstance(exc.value, LegacyAttachment)


def test_humble_service_token_is_named():
    key = ("@ros2_lv/0/aabbccdd/0/11/SS/%/%/humble_node/%add_two_ints/"
           "example_interfaces::srv::dds_::AddTwoInts_/TypeHashNotSupported/::,10:,:,:,,")
    info = parse_service_token(key)
    assert info.humble and info.service_name == "/add_two_ints" and info.service_type == ADD
    assert not parse_service_token(key.replace("TypeHashNotSupported", ADD_HASH)).humble


# -- over real sessions: a call each way with zenoh-ros2-sdk ----------------------------------------
def test_we_call_an_sdk_service(router):
    domain = domain_id()
    peer = python_proc("-c", SDK_SERVER, str(router), str(domain), "/add_two_ints")
    try:
        ready = read_line(peer, "ready")
        srv = ros2_service_type(ADD)
        assert ready.endswith(service_data_key(domain, "/add_two_ints", srv))   # the same key on both sides
        with ros2_node("adder_client", router, domain) as node:
            client = node.create_client("/add_two_ints", srv.request, srv.response)
            assert client.wait_for_service(10.0)
            assert client.call(srv.request(a=20, b=22), timeout=5.0) == srv.response(sum=42)
            # Its server and our client are on the ROS 2 graph with the service's type and hash.
            assert wait_for(lambda: {("SS", "sdk_adder"), ("SC", "adder_client")} <= {
                (i.kind, i.node_name) for i in ros2_services(node.session, domain)
                if i.service_name == "/add_two_ints" and i.service_type == ADD and i.type_hash == ADD_HASH}, 10.0)
    finally:
        kill_process(peer)


def test_sdk_calls_our_service(router):
    domain = domain_id()
    srv = ros2_service_type("std_srvs/srv/SetBool")
    calls = []

    def handle(req):
        calls.append(req.data)
        return srv.response(success=req.data, message="switched on" if req.data else "off")

    with ros2_node("switch", router, domain) as node:
        server = node.create_service("/switch", srv.request, srv.response, handle)
        assert server.key == f"{domain}/switch/std_srvs::srv::dds_::SetBool_/{srv.hash}"
        peer = python_proc("-c", SDK_CLIENT, str(router), str(domain), "/switch")
        try:
            end = time.monotonic() + 40
            line = ""
            while time.monotonic() < end and not line:
                node.spin_once(0.05)
                line = _poll_line(peer)
            assert line == "reply True switched on", line
            assert calls == [True] and server.served == 1
        finally:
            kill_process(peer)


def _poll_line(proc) -> str:
    import select

    while select.select([proc.stdout], [], [], 0)[0]:
        line = proc.stdout.readline()
        if not line:
            return "eof"
        if line.startswith(("reply", "no reply")):
            return line.strip()
    return ""


def test_legacy_or_missing_attachment_gets_an_error_not_silence(router, caplog):
    """A request without rmw_zenoh's attachment, or with the labelled one of Jazzy <= 0.2.3, is
    answered with an error naming the problem, and warned about once per peer (never silence)."""
    domain = domain_id()
    srv = ros2_service_type(ADD)
    with ros2_node("adder", router, domain) as node:
        server = node.create_service("/add_two_ints", srv.request, srv.response,
                                     lambda r: srv.response(sum=r.a + r.b))
        payload = srv.encode_request(srv.request(a=1, b=2))
        legacy = b"\x0fsequence_number\x08" + bytes(8) + b"\x10source_timestamp\x08" + bytes(8) \
            + b"\x0asource_gid\x10" + bytes(16)
        caplog.set_level(logging.WARNING, logger="zenoh_robot.services")
        errors = []
        for attachment in (legacy, legacy, None):
            replies = list(node.session.get(server.key, payload=payload, attachment=attachment, timeout=5.0))
            assert len(replies) == 1 and replies[0].ok is None
            errors.append(replies[0].err.payload.to_bytes().decode())
        assert "0.2.3" in errors[0] and "no attachment" in errors[2]
        assert server.legacy_requests == 2 and server.served == 0
        assert sum("0.2.3" in r.getMessage() for r in caplog.records) == 1     # once per peer
        # A well-formed request right after is served, the request id (seq, client GID) echoed.
        gid = bytes(range(16))
        with spinning(node):
            replies = list(node.session.get(server.key, payload=payload,
                                            attachment=pack_attachment(9, time.time_ns(), gid), timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is not None
        assert srv.decode_response(replies[0].ok.payload.to_bytes()) == srv.response(sum=3)
        seq, _stamp, echoed = unpack_attachment(replies[0].ok.attachment.to_bytes())
        assert (seq, echoed) == (9, gid) and server.served == 1


def test_our_client_and_server_on_the_ros2_wire(router):
    """Both sides ours, a handler error arriving as a ServiceError, and the envelope untouched:
    a ROS 2 node's parameter service (non-ROS types) keeps the envelope's @srv key."""
    domain = domain_id()
    srv = ros2_service_type(ADD)

    def add(req):
        if req.a < 0:
            raise ValueError("negative")
        return srv.response(sum=req.a + req.b)

    with ros2_node("srv_side", router, domain) as server_node, ros2_node("cli_side", router, domain) as client_node:
        server = server_node.create_service("add_two_ints", srv.request, srv.response, add)
        assert server.key == service_data_key(domain, "/add_two_ints", srv)
        with spinning(server_node):
            client = client_node.create_client("/add_two_ints", srv.request, srv.response)
            assert client.wait_for_service(10.0)
            assert client.call(srv.request(a=1, b=2), timeout=5.0).sum == 3
            with pytest.raises(ServiceError, match="negative"):
                client.call(srv.request(a=-1, b=2), timeout=5.0)
        # Types that are not a ROS 2 service's keep the envelope on a ROS 2 node (the parameter service).
        assert any(s.key.startswith("@srv/") for s in server_node.services)


@contextlib.contextmanager
def spinning(node: Node):
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            node.spin_once(0.05)
    thread = threading.Thread(target=spin)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
