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


def _fields(types: dict[str, Any], type_name: str) -> dict[str, Any]:
    """The bench's sample of ``type_name`` (as ``ros2.sample``), header aside, as the SDK's classes."""
    if type_name.endswith("PoseStamped"):
        return {"pose": types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=1.5, y=0.0, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))}
    if type_name.endswith("CompressedImage"):
        import numpy as np
        return {"format": "jpeg", "data": np.frombuffer(bytes(range(256)) * 256, dtype=np.uint8)}
    raise ValueError(f"bench: no zenoh-ros2-sdk sample of {type_name} (PoseStamped, CompressedImage)")


def _header(types: dict[str, Any], ns: int) -> Any:
    stamp = types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id="base_link")


def _warm(store: Any, type_name: str) -> None:
    # rosbags generates a type's CDR code on its first use (~10 ms): done before the flow, as the
    # other modes' codecs are built when their publisher or subscription is made.
    msg = store.types[type_name](header=_header(store.types, 0), **_fields(store.types, type_name))
    store.deserialize_cdr(bytes(store.serialize_cdr(msg, type_name)), type_name)


def subscribe(type_name: str, port: int, throughput: bool, record: Callable[[int], None]) -> Any:
    """A ROS2Subscriber whose callback records each message's ``header.stamp`` (ns)."""
    from zenoh_ros2_sdk import ROS2Subscriber

    common, root = _prepare(type_name, port, "sub")

    def on_message(msg: Any) -> None:
        stamp = msg.header.stamp
        record(stamp.sec * 1_000_000_000 + stamp.nanosec)
    try:
        sub = ROS2Subscriber(TOPIC, type_name, on_message, node_name="bench_sub", qos=_qos(throughput), **common)
        _warm(sub.session_mgr.store, type_name)
    finally:
        shutil.rmtree(root, ignore_errors=True)     # every type it needs is in its store by now
    return sub


def publisher(type_name: str, port: int, throughput: bool) -> Callable[[], None]:
    """``send()``: one publish of the bench's sample of ``type_name``, stamped now."""
    from zenoh_ros2_sdk import ROS2Publisher

    common, root = _prepare(type_name, port, "pub")
    try:
        pub = ROS2Publisher(TOPIC, type_name, node_name="bench_pub", qos=_qos(throughput), **common)
        _warm(pub.session_mgr.store, type_name)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    types = pub.session_mgr.store.types
    fields = _fields(types, type_name)
    publish, now = pub.publish, time.time_ns

    def send() -> None:
        publish(header=_header(types, now()), **fields)
    return send
