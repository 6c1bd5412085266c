"""A Foxglove WebSocket client for the tests: the `websockets` package speaking foxglove.websocket.v1,
as Foxglove and Lichtblick do (advertise, subscribe, binary MESSAGE_DATA frames)."""
from __future__ import annotations

import asyncio
import json
import re
import struct
import time
from collections.abc import Callable, Iterable
from typing import Any

import websockets as websockets

SUBPROTOCOL = "foxglove.websocket.v1"     # the protocol's published name (Foxglove, Lichtblick)
# foxglove-sdk >= 0.2x names the same protocol foxglove.sdk.v1 in its handshake: offer both, as apps do.
SUBPROTOCOLS = [SUBPROTOCOL, "foxglove.sdk.v1"]
MESSAGE_DATA = 0x01
UNKNOWN_CHANNEL = re.compile(r"Unknown channel ID: (\d+)")
MAX_RESUBSCRIBES = 50

Channels = dict[str, dict[str, Any]]


async def watch(port: int, timeout: float, done: Callable[[Channels, dict[str, bytes]], bool], *,
                subscribe: Callable[[Channels], Iterable[str]] = lambda channels: (),
                retry_connect: bool = False) -> tuple[Channels, dict[str, bytes]]:
    """Channels advertised (topic -> channel) and the first message of each topic subscribed to, once
    ``done(channels, messages)`` or at ``timeout``. ``subscribe(channels)`` names the topics to subscribe
    to as they are advertised; each new subscription restarts the timeout (a busy box may be slow to send).
    ``retry_connect``: a server starting beside the test is retried until it listens."""
    channels: Channels = {}
    got: dict[str, bytes] = {}
    deadline = time.monotonic() + timeout
    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS,  # type: ignore[arg-type]
                                          max_size=None, open_timeout=min(timeout, 2.0) if retry_connect else timeout)
            break
        except OSError:
            if not retry_connect or time.monotonic() >= deadline:
                raise
            await asyncio.sleep(0.3)
    by_sub: dict[int, str] = {}            # subscription id -> topic
    sub_of_channel: dict[int, int] = {}    # channel id -> subscription id
    retries = 0
    async with ws:
        assert ws.subprotocol in SUBPROTOCOLS, ws.subprotocol
        while time.monotonic() < deadline and not done(channels, got):
            try:
                raw = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(raw, str):
                msg = json.loads(raw)
                unknown = UNKNOWN_CHANNEL.fullmatch(str(msg.get("message", ""))) if msg.get("op") == "status" else None
                if unknown and retries < MAX_RESUBSCRIBES and int(unknown[1]) in sub_of_channel:
                    # foxglove-sdk sends a channel's advertise before the channel is registered for the
                    # client; a subscribe that fast is refused as unknown. Ask again, as a person would.
                    retries += 1
                    await asyncio.sleep(0.05)
                    channel_id = int(unknown[1])
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": sub_of_channel[channel_id], "channelId": channel_id}]}))
                if msg.get("op") != "advertise":
                    continue
                channels.update({ch["topic"]: ch for ch in msg["channels"]})
                subs = []
                for topic in subscribe(channels):
                    # By channel id: a topic advertised again (a new id) is subscribed to again.
                    if topic in channels and channels[topic]["id"] not in sub_of_channel:
                        by_sub[len(by_sub) + 1] = topic
                        sub_of_channel[channels[topic]["id"]] = len(by_sub)
                        subs.append({"id": len(by_sub), "channelId": channels[topic]["id"]})
                if subs:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    deadline = time.monotonic() + timeout
            elif raw and raw[0] == MESSAGE_DATA:
                sub_id, _log_time = struct.unpack_from("<IQ", raw, 1)
                got.setdefault(by_sub[sub_id], bytes(raw[13:]))
    return channels, got
