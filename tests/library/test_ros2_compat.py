"""rmw_zenoh peers that exchange no data with Jazzy 0.2.4+ are named, not silent (zenoh_robot.ros2.compat):
a Humble-style token (``TypeHashNotSupported`` where the hash goes) and a sample with the labelled
attachment of rmw_zenoh <= 0.2.3, each sent by a plain zenoh-python session as those peers would, over
real sessions to a zenoh-robot node on the ROS 2 wire: counted, warned about once by name, and shown by
``zenoh-robot topic info``.
"""
from __future__ import annotations

import logging
import struct
import subprocess

import pytest
import zenoh
from conftest import CLI, ROOT, free_port, fresh_domain, wait_for

from zenoh_robot import Node, QoSProfile, SessionConfig
from zenoh_robot.message import type_support
from zenoh_robot.ros2 import compat, ros2_type, typestore
from zenoh_robot.wire import ros2_wire


def _raw_session(port: int) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@pytest.fixture
def ros2_node():
    domain = fresh_domain()
    port = free_port()
    config = SessionConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False, shared_memory=False)
    with Node("zr_listener", config=config, wire=ros2_wire(domain)) as node:
        yield node, domain, port


def test_a_humble_peer_is_counted_named_once_and_shown_by_topic_info(ros2_node, caplog) -> None:
    node, domain, port = ros2_node
    before = compat.summary()
    caplog.set_level(logging.WARNING, logger="zenoh_robot.ros2")
    session = _raw_session(port)
    try:
        zid = str(session.zid())
        # rmw_zenoh Humble's publisher token: the Jazzy layout, no RIHS01 hash.
        key = (f"@ros2_lv/{domain}/{zid}/0/11/MP/%/%/humble_talker/%chatter/std_msgs::msg::dds_::String_/"
               f"{compat.HUMBLE_TYPE_HASH}/1:2:1,10:,:,:,,")
        token = session.liveliness().declare_token(key)
        node_token = session.liveliness().declare_token(f"@ros2_lv/{domain}/{zid}/0/0/NN/%/%/humble_talker")
        assert wait_for(lambda: compat.summary()["humble_peers"] > before["humble_peers"], 10.0)
        node.refresh_graph(1.0)
        warnings = [r.getMessage() for r in caplog.records if r.name == "zenoh_robot.ros2"]
        assert len(warnings) == 1 and "/humble_talker" in warnings[0] and zid in warnings[0], warnings
        # the same peer again (another token of it) is counted, not said twice
        second = session.liveliness().declare_token(key.replace("/0/11/", "/0/12/"))
        assert wait_for(lambda: compat.summary()["humble_tokens"] >= before["humble_tokens"] + 2, 10.0)
        assert len([r for r in caplog.records if r.name == "zenoh_robot.ros2"]) == 1
        r = subprocess.run([*CLI, "topic", "info", "/chatter", "--ros-domain-id", str(domain),
                            "-e", f"tcp/127.0.0.1:{port}", "-l", "tcp/127.0.0.1:0"],
                           cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        assert "ROS 2 Humble: 2 endpoints without a type hash" in r.stdout, r.stdout + r.stderr
        for t in (token, node_token, second):
            t.undeclare()
    finally:
        session.close()


def test_a_legacy_attachment_is_counted_and_named_by_its_gid(ros2_node, caplog) -> None:
    node, domain, port = ros2_node
    String = ros2_type("std_msgs/msg/String")
    sub = node.create_subscription(String, "/chatter", lambda m: None, QoSProfile(depth=10))
    before = compat.summary()
    caplog.set_level(logging.WARNING, logger="zenoh_robot.ros2")
    store = typestore()
    payload = bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data="old"), "std_msgs/msg/String"))
    gid = bytes(range(0xA0, 0xB0))
    # rmw_zenoh <= 0.2.3: each value after its label
    legacy = (b"sequence_number" + struct.pack("<q", 1) + b"source_timestamp" + struct.pack("<q", 2)
              + b"source_gid" + gid)
    session = _raw_session(port)
    try:
        pub = session.declare_publisher(
            f"{domain}/chatter/std_msgs::msg::dds_::String_/{type_support(String).hash}")
        node.refresh_graph(0.5)

        def sent_and_seen() -> bool:
            pub.put(payload, attachment=legacy)
            node.spin_once(0.05)
            return sub.counters.malformed >= 3
        assert wait_for(sent_and_seen, 15.0)
        after = compat.summary()
        assert after["legacy_attachments"] >= before["legacy_attachments"] + 3
        assert after["legacy_peers"] == before["legacy_peers"] + 1
        warnings = [r.getMessage() for r in caplog.records if r.name == "zenoh_robot.ros2"]
        assert len(warnings) == 1 and gid.hex() in warnings[0], warnings
        pub.undeclare()
    finally:
        session.close()
