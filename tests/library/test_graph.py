"""The graph over liveliness tokens: names, types, counts and QoS of endpoints in other processes."""
from __future__ import annotations

import textwrap

import pytest
from conftest import linked_configs, python_proc, wait_for

from zenoh_robot import Node, QoSProfile, qos
from zenoh_robot.graph import (
    EndpointType,
    NodeInfo,
    TopicEndpointInfo,
    decode_qos,
    encode_qos,
    endpoint_token_key,
    node_token_key,
    parse_token,
)

ODD = QoSProfile(reliability="best_effort", durability="transient_local", history="keep_all", depth=0,
                 deadline=0.25, lifespan=1.5, liveliness="manual_by_topic", liveliness_lease_duration=0.75,
                 priority="real_time", express=True, redundancy=8, repeat=3)


@pytest.mark.fast
@pytest.mark.parametrize("profile", [QoSProfile(), ODD, *qos.PRESETS.values()])
def test_qos_survives_the_token_key(profile):
    assert decode_qos(encode_qos(profile)) == profile


@pytest.mark.fast
def test_token_keys_parse_back():
    key = endpoint_token_key("MP", "abc123", 42, "uav1/cam", "camera", "uav1/cam/image", "zenoh_robot/Image",
                             "deadbeef", ODD)
    info = parse_token(key)
    assert isinstance(info, TopicEndpointInfo)
    assert (info.node_name, info.node_namespace, info.topic_name, info.topic_type) == \
        ("camera", "/uav1/cam", "/uav1/cam/image", "zenoh_robot/Image")
    assert info.endpoint_type is EndpointType.PUBLISHER and info.endpoint_gid == 42 and info.qos_profile == ODD
    assert parse_token(node_token_key("abc", "", "gcs")) == NodeInfo("gcs", "/", "abc")
    for bad in ("@zr/lv/XX/a/1/%/n/t/T/h/q", "@zr/lv/MP/a/notanint/%/n/t/T/h/1:1:1:1::::1:::5:0", "foo/bar"):
        with pytest.raises(ValueError):
            parse_token(bad)


CHILD = textwrap.dedent("""
    import sys
    from zenoh_robot import Node, QoSProfile, SessionConfig, qos
    from zenoh_robot.msgs import Setpoint, String
    cfg = SessionConfig(listen=[], connect=sys.argv[1].split(","), multicast_scouting=False, shared_memory=False)
    with Node("talker", namespace=sys.argv[2], config=cfg) as node:
        node.create_publisher(Setpoint, "setpoint", qos.RESILIENT)
        node.create_subscription(String, "~/cmd", print, QoSProfile(depth=7, deadline=0.5))
        print("ready", flush=True)
        sys.stdin.readline()      # the test closes stdin: a clean exit
""")


def test_graph_sees_another_process_and_forgets_it_when_it_exits(ns):
    import subprocess
    listen, connect = linked_configs()
    with Node("observer", namespace=ns, config=listen) as node:
        child = python_proc("-c", CHILD, ",".join(connect.connect), ns, stdin=subprocess.PIPE)
        try:
            assert wait_for(lambda: node.count_publishers("setpoint") == 1 and
                            node.count_subscribers(f"/{ns}/talker/cmd") == 1, 15.0), node.get_topic_names_and_types()
            topics = dict(node.get_topic_names_and_types())
            assert topics[f"/{ns}/setpoint"] == ["zenoh_robot/Setpoint"]
            assert topics[f"/{ns}/talker/cmd"] == ["std_msgs/String"]
            (pub,) = node.get_publishers_info_by_topic("setpoint")
            assert (pub.node_name, pub.node_namespace, pub.qos_profile) == ("talker", f"/{ns}", qos.RESILIENT)
            assert pub.endpoint_type is EndpointType.PUBLISHER
            (sub,) = node.get_subscriptions_info_by_topic(f"/{ns}/talker/cmd")
            assert sub.qos_profile.depth == 7 and sub.qos_profile.deadline == 0.5
            assert ("talker", f"/{ns}") in node.get_node_names_and_namespaces()
            assert "observer" in node.get_node_names()
            child.stdin.close()
            assert child.wait(10) == 0
            assert wait_for(lambda: node.count_publishers("setpoint") == 0 and
                            ("talker", f"/{ns}") not in node.get_node_names_and_namespaces(), 3.0)
        finally:
            child.kill()
            child.wait(5)


@pytest.mark.fast
def test_destroyed_entities_leave_the_graph(ns):
    listen, connect = linked_configs()
    with Node("a", namespace=ns, config=listen) as a, Node("b", namespace=ns, config=connect) as b:
        from zenoh_robot.msgs import String
        pub = a.create_publisher(String, "chatter")
        assert wait_for(lambda: b.count_publishers("chatter") == 1, 5.0)
        a.destroy_publisher(pub)
        assert wait_for(lambda: b.count_publishers("chatter") == 0, 5.0)
        assert f"/{ns}/chatter" not in dict(b.get_topic_names_and_types())
