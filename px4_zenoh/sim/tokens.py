"""PX4's ``@ros2_lv`` liveliness tokens, in exactly the form its zenoh module declares them.

PX4 (src/modules/zenoh) declares one node token in domain 0 whatever ZENOH_DOMAIN_ID says, and one
token per entity in ZENOH_DOMAIN_ID, all with node id 0 and entity id 11, node name
``px4_<GID hex>``, and the QoS chunk ``::,7:,:,:,,`` (RELIABLE depth 7 advertised for every entity).
The zid chunk is the session's ZenohId bytes in the opposite order to zenoh-python's ``str(zid)``.
"""
from __future__ import annotations

from px4_zenoh.topics import OUT, Px4Topic
from zenoh_robot.wire.ros2 import ADMIN_SPACE, NODE, PUBLISHER, SUBSCRIPTION, mangle

GID = bytes.fromhex("aabbcc00000000000000000000000000")
NODE_NAME = "px4_" + GID.hex()
QOS = "::,7:,:,:,,"
ENTITY_ID = 11


def token_zid(session_zid: str) -> str:
    """PX4's zid chunk: the byte-reversed hex of zenoh-python's ``str(zid)``."""
    text = session_zid if len(session_zid) % 2 == 0 else "0" + session_zid
    return bytes.fromhex(text)[::-1].hex()


def node_token(zid: str) -> str:
    return f"{ADMIN_SPACE}/0/{zid}/0/0/{NODE}/%/%/{NODE_NAME}"


def entity_token(zid: str, domain: int, topic: Px4Topic, type_hash: str) -> str:
    kind = PUBLISHER if topic.direction == OUT else SUBSCRIPTION
    return (f"{ADMIN_SPACE}/{domain}/{zid}/0/{ENTITY_ID}/{kind}/%/%/{NODE_NAME}/{mangle(topic.name)}/"
            f"{topic.dds_type}/{type_hash}/{QOS}")
