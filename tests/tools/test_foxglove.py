"""`zenoh-robot foxglove`: a Foxglove WebSocket client (the `websockets` package, subprotocol
foxglove.websocket.v1) sees every topic advertised, with typed views, and receives camera frames.

Real parts: a talker Node on loopback sockets (vehicle state, setpoints, JPEG image slices),
the bridge as its own process, a WebSocket client speaking the protocol.
"""
from __future__ import annotations

import asyncio
import json
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
from conftest import free_port, linked_configs, python_proc
from foxglove_client import watch

from drone_contract.messages import VehicleState  # noqa: E402
from zenoh_robot import Node, msgs, qos  # noqa: E402
from zenoh_robot.image.sliced import ImagePublisher  # noqa: E402


def _publish(node: Node, stop: threading.Event) -> None:
    state = node.create_publisher(VehicleState, "state")
    setpoint = node.create_publisher(msgs.Setpoint, "setpoint", qos.SETPOINT)
    camera = ImagePublisher(node, "image", qos.IMAGE, quality=60)
    frame = np.zeros((64, 96, 3), dtype=np.uint8)
    i = 0
    while not stop.is_set():
        state.publish(VehicleState(msgs.Header.now(), mode="OFFBOARD", position=[1.0, 2.0, -3.0 - i * 0.01]))
        setpoint.publish(msgs.Setpoint(msgs.Header.now(), x=1.0, y=2.0, z=-5.0))
        if i % 5 == 0:
            frame[:, :, 1] = i % 255
            camera.publish(frame)
        i += 1
        time.sleep(0.02)


def test_bridge_advertises_topics_and_streams_camera_frames(ns: str, tmp_path: Path):
    listen, connect = linked_configs()
    cfg = tmp_path / "connect.json5"
    cfg.write_text(json.dumps(connect.to_json5()))
    port = free_port()
    stop = threading.Event()
    with Node("drone", namespace=ns, config=listen) as node:
        pub = threading.Thread(target=_publish, args=(node, stop), daemon=True)
        pub.start()
        bridge = python_proc("-c", "import sys; from zenoh_robot.tools.cli.main import main; sys.exit(main())",
                             "foxglove", "--zenoh", str(cfg), "--port", str(port))
        try:
            assert bridge.stdout is not None
            lines = []
            while not any(f"ws://127.0.0.1:{port}" in x for x in lines) and bridge.poll() is None:
                lines.append(bridge.stdout.readline())
            assert bridge.poll() is None, "".join(lines)
            # keep reading the bridge's output so a full pipe never stalls it
            threading.Thread(target=lambda: lines.extend(bridge.stdout), daemon=True).start()
            want = {f"/{ns}/state", f"/{ns}/state/pose", f"/{ns}/state/fix", "/tf", f"/{ns}/setpoint/pose",
                    f"/{ns}/image/image"}
            image_topic = f"/{ns}/image/image"
            channels, got = asyncio.run(watch(port, 20.0, lambda channels, got: bool(got),
                                              subscribe=lambda ch: [image_topic] if want <= set(ch) else []))
            payload = got.get(image_topic, b"")
        finally:
            stop.set()
            pub.join()
            bridge.terminate()
            try:
                out, _ = bridge.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                bridge.kill()
                out, _ = bridge.communicate()
    assert want <= set(channels), f"advertised: {sorted(channels)}"
    state = channels[f"/{ns}/state"]
    assert state["encoding"] == "json" and state["schemaName"] == "zenoh_robot/VehicleState"
    assert {"position", "attitude", "armed"} <= set(json.loads(state["schema"])["properties"])
    assert channels[f"/{ns}/state/fix"]["schemaName"] == "foxglove.LocationFix"
    assert channels["/tf"]["schemaName"] == "foxglove.FrameTransform"
    image = channels[f"/{ns}/image/image"]
    assert image["schemaName"] == "foxglove.CompressedImage" and image["encoding"] == "protobuf"
    assert f"/{ns}/image" not in channels, "the slices are sent as frames only, not as base64 JSON"
    # The frame, reassembled from its slices, re-encoded as one JPEG inside the protobuf message.
    assert b"\xff\xd8\xff" in payload and b"jpeg" in payload, payload[:40]
    assert bridge.returncode == 0, out
