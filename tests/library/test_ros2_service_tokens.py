"""Service tokens as rmw_zenoh writes and reads them (issue #40, defect 1).

rmw_zenoh's docs/design.md: ``<mangled_qualified_name>`` is "the mangled fully qualified name of the
topic or service (i.e. including namespace, if any)", and its example server token is::

    @ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/%add_two_ints/
    example_interfaces::srv::dds_::AddTwoInts_/RIHS01_e118de6b.../::,10:,:,:,,

Our tokens once dropped the leading '%' (``.../zr_node/zr%set_flag/...``): rmw_zenoh demangles that to
``zr/set_flag``, which never equals a client's ``/zr/set_flag``, so ``wait_for_service()`` never returned.
The live check reads the tokens with ``ros2_peer.rmw_zenoh_entity`` (rmw_zenoh's parse, not ours).
"""
from __future__ import annotations

from conftest import fresh_domain, wait_for
from ros2_peer import RmwZenohGraph, rmw_zenoh_entity, rmw_zenoh_service_available
from ros2_peer import router as ros2_router

from zenoh_robot import Node
from zenoh_robot.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from zenoh_robot.ros2 import ros2_service_type
from zenoh_robot.services import parse_service_token, ros2_services
from zenoh_robot.session_config import SessionConfig
from zenoh_robot.wire.ros2 import Ros2Graph, ros2_wire

ADD = "example_interfaces/srv/AddTwoInts"
ADD_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
# rmw_zenoh docs/design.md, "Graph Cache": the add_two_ints_server's service server, verbatim.
SPEC_SS = ("@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/%add_two_ints/"
           f"example_interfaces::srv::dds_::AddTwoInts_/{ADD_HASH}/::,10:,:,:,,")
SERVICES_QOS = QoSProfile(ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST, 10)


def _fields(key: str) -> list[str]:
    """Every field but the ids and the QoS (ours are per session, and our QoS is written explicit)."""
    parts = key.split("/")
    return parts[:3] + parts[5:12]


def test_our_service_token_is_the_documented_form() -> None:
    graph = Ros2Graph(2)
    ours = graph.entity_token("SS", "f9980ee0495eaafb3e38f0d19e2eae12", 7, "/", "add_two_ints_server",
                              "add_two_ints", ADD, ADD_HASH, SERVICES_QOS)
    assert _fields(ours) == _fields(SPEC_SS)
    assert "/add_two_ints_server/%add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/" in ours


def test_a_namespaced_service_token_names_the_fully_qualified_service() -> None:
    srv = ros2_service_type("std_srvs/srv/SetBool")
    token = Ros2Graph(0).entity_token("SS", "aa", 1, "/zr", "zr_node", "zr/set_flag", srv.name, srv.hash,
                                      SERVICES_QOS)
    assert f"/SS/%/%zr/zr_node/%zr%set_flag/std_srvs::srv::dds_::SetBool_/{srv.hash}/" in token
    assert rmw_zenoh_entity(token)["name"] == "/zr/set_flag"        # the peer's reading


def test_our_reader_reads_the_spec_example_and_not_the_old_form() -> None:
    info = parse_service_token(SPEC_SS)
    assert (info.kind, info.node_namespace, info.node_name) == ("SS", "/", "add_two_ints_server")
    assert (info.service_name, info.service_type, info.type_hash) == ("/add_two_ints", ADD, ADD_HASH)
    # The old, wrong form reads as rmw_zenoh reads it: a name no ROS 2 client asks for.
    old = SPEC_SS.replace("/%add_two_ints/", "/add_two_ints/")
    assert parse_service_token(old).service_name == "add_two_ints"
    assert rmw_zenoh_entity(old)["name"] == "add_two_ints"


def test_an_rmw_zenoh_graph_finds_our_namespaced_server_and_client() -> None:
    """Over real sessions through a router: the tokens our server and client declare, read the way
    rmw_zenoh's graph cache reads them, answer rcl's ``/zr/set_flag`` (what wait_for_service asks)."""
    domain = fresh_domain()
    srv = ros2_service_type("std_srvs/srv/SetBool")
    with ros2_router() as port:
        config = SessionConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"],
                               multicast_scouting=False)
        with Node("zr_node", "zr", config=config, wire=ros2_wire(domain)) as node, \
                Node("zr_caller", config=config, wire=ros2_wire(domain)) as caller:
            node.create_service("set_flag", srv.request, srv.response,
                                lambda r: srv.response(success=r.data, message=""))
            caller.create_client("/zr/set_flag", srv.request, srv.response)
            graph = RmwZenohGraph(caller.session, domain)
            try:
                assert wait_for(lambda: rmw_zenoh_service_available(graph.keys(), "/zr/set_flag", srv.dds_name,
                                                                    srv.hash), 10.0)

                def services() -> set[tuple[str, ...]]:
                    return {(e["entity"], e["namespace"], e["node_name"], e["name"])
                            for e in graph.entities("SS", "SC")}
                assert wait_for(lambda: {("SS", "/zr", "zr_node", "/zr/set_flag"),
                                         ("SC", "/", "zr_caller", "/zr/set_flag")} <= services(), 10.0), services()
                assert all(name.startswith("/") for *_, name in services())
            finally:
                graph.close()
            # And our own reader agrees with rmw_zenoh's on every one of them.
            ours = {(i.kind, i.node_namespace, i.node_name, i.service_name)
                    for i in ros2_services(caller.session, domain)}
            assert services() <= ours, ours
