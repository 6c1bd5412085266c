"""The other Python implementation of rmw_zenoh's wire in ``zenoh-robot bench --ros2``: zenoh-ros2-sdk (PyPI).

Its side of a cell is what its users write: a ``ROS2Publisher`` whose ``publish(**fields)`` builds and
serialises the message, a ``ROS2Subscriber`` whose callback gets the decoded message, each on the session
its shipped configuration opens (rmw_zenoh's default, peer mode), pointed at the other side's port as the
other modes are: the subscriber listens, the publisher connects.

Its callback gets the message and nothing else (no attachment, no source stamp), so the publisher writes
the send time into the message's ``header.stamp`` just before ``publish``, as a ROS 2 user does, and the
subscriber's age is now minus that stamp. The other modes stamp inside ``publish`` after the fields are
taken; here the stamp also comes before the SDK builds the message object, which ages it by that step.

The SDK would fetch the ``.msg`` files it needs from GitHub; it is handed them from this package's own
definitions (``zenoh_robot.ros2.msg_definition``), so it runs offline and computes its own type hashes.
"""
from __future__ import annotations

import dataclasses
import importlib.util
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

PACKAGE = "zenoh_ros2_sdk"
MISSING = "zenoh-ros2-sdk is not installed: pip install 'zenoh-robot[bench]'"
TOPIC = "/bench/ros2"


def available() -> bool:
    return importlib.util.find_spec(PACKAGE) is not None


def _prepare(type_name: str, port: int, role: str) -> tuple[dict[str, Any], Path]:
    """The SDK's registry on a directory of our .msg files (removed by the caller once the SDK has read them);
    its session's endpoints (read when it opens)."""
    from zenoh_ros2_sdk import message_registry

    from zenoh_robot.ros2 import dependencies, msg_definition

    root = Path(tempfile.mkdtemp(prefix="zr-bench-sdk-"))
    for name in [type_name, *dependencies(type_name)]:
        pkg, kind, short = name.split("/")
        path = root / pkg / kind / f"{short}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(msg_definition(name))
    message_registry._registry = message_registry.MessageRegistry(str(root))
    override = "scouting/multicast/enabled=false"
    if role == "sub":
        override += f';listen/endpoints=["tcp/127.0.0.1:{port}"];connect/endpoints=[]'
    os.environ["ZENOH_CONFIG_OVERRIDE"] = override
    return {"domain_id": 0, "router_ip": "127.0.0.1", "router_port": port}, root


def _qos(throughput: bool) -> Any:
    from zenoh_ros2_sdk.qos import QosHistoryKind, QosProfile

    # Reliable (the SDK's publisher then blocks, as the others' do); KEEP_ALL for throughput, as theirs.
    if throughput:
        return QosProfile(history_kind=QosHistoryKind.KEEP_ALL, history_depth=0)
    return QosProfile(history_depth=100)


def _header(types: dict[str, Any], ns: int, frame_id: str) -> Any:
    stamp = types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def _message(store: Any, type_name: str, sample_cdr: bytes) -> Any:
    """The bench's sample (``ros2.sample``, as its CDR bytes) as the SDK's own message object. Going through
    the SDK's codec both ways also builds the CDR code rosbags generates on first use (~10 ms) before the
    flow, as the other modes' codecs are built when their publisher or subscription is made."""
    msg = store.deserialize_cdr(sample_cdr, type_name)
    store.serialize_cdr(msg, type_name)
    return msg


def subscribe(type_name: str, port: int, throughput: bool, sample_cdr: bytes,
              record: Callable[[int], None]) -> Any:
    """A ROS2Subscriber whose callback records each message's ``header.stamp`` (ns)."""
    from zenoh_ros2_sdk import ROS2Subscriber

    common, root = _prepare(type_name, port, "sub")

    def on_message(msg: Any) -> None:
        stamp = msg.header.stamp
        record(stamp.sec * 1_000_000_000 + stamp.nanosec)
    try:
        sub = ROS2Subscriber(TOPIC, type_name, on_message, node_name="bench_sub", qos=_qos(throughput), **common)
        _message(sub.session_mgr.store, type_name, sample_cdr)
    finally:
        shutil.rmtree(root, ignore_errors=True)     # every type it needs is in its store by now
    return sub


def publisher(type_name: str, port: int, throughput: bool, sample_cdr: bytes) -> Callable[[], None]:
    """``send()``: one publish of the bench's sample of ``type_name`` (its CDR bytes), stamped now."""
    from zenoh_ros2_sdk import ROS2Publisher

    common, root = _prepare(type_name, port, "pub")
    try:
        pub = ROS2Publisher(TOPIC, type_name, node_name="bench_pub", qos=_qos(throughput), **common)
        msg = _message(pub.session_mgr.store, type_name, sample_cdr)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    types = pub.session_mgr.store.types
    # publish(**fields) builds the message each time, as its users call it; the header is new each time.
    # (rosbags' own __msgtype__ field left to its default)
    fields = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)
              if f.name != "header" and not f.name.startswith("__")}
    frame_id = msg.header.frame_id
    publish, now = pub.publish, time.time_ns

    def send() -> None:
        publish(header=_header(types, now(), frame_id), **fields)
    return send
