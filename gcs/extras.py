"""What ``gcs`` runs beside the dashboard on request: the MCAP flight log (``--record FILE.mcap``),
the live Foxglove bridge (``--foxglove``) and the MAVLink re-emitter for QGC (``--mavlink-out``).

``ExtrasOptions`` is what the CLI validated; ``GcsExtras`` starts what it asks for on the GCS's
node and closes it at the end, the flight log with the run's summary in it.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zenoh_robot import Node

from .mavlink_out import MavlinkOut

if TYPE_CHECKING:
    from zenoh_robot.tools.bag.record import BagRecorder
    from zenoh_robot.tools.foxglove_bridge import FoxgloveBridge

MAVLINK_PORT_STEP = 10   # drone i's MAVLink goes to the first port + 10 i: one QGC comm link per drone


@dataclass(frozen=True)
class ExtrasOptions:
    record: Path | None = None                   # recorded live when it names a .mcap file
    foxglove_port: int | None = None
    mavlink_out: tuple[str, int] | None = None   # (host, port) of drone 0 (mavlink_out.parse_udpout)


class GcsExtras:
    def __init__(self, node: Node, options: ExtrasOptions, drones: list[str], say: Callable[[str], None]) -> None:
        self.recorder: BagRecorder | None = None
        self.bridge: FoxgloveBridge | None = None
        self.outs: list[MavlinkOut] = []
        record = options.record
        if record is not None and str(record).lower().endswith(".mcap"):
            from zenoh_robot.tools.bag.record import BagRecorder
            self.recorder = BagRecorder(node, record, None)
            self.recorder.start()
            say(f"gcs: recording every topic to {record}")
        if options.foxglove_port is not None:
            from zenoh_robot.tools.foxglove_bridge import FoxgloveBridge
            self.bridge = FoxgloveBridge(node, None, port=options.foxglove_port)
            self.bridge.start()
            say(f"gcs: Foxglove live view on {self.bridge.url} ({self.bridge.app_url()})")
        if options.mavlink_out is not None:
            host, port = options.mavlink_out
            # Without --drones the drones are not known yet: the first one's id is the default companion's.
            for i, drone in enumerate(drones or ["uav1"]):
                self.outs.append(MavlinkOut(node, drone, f"udpout:{host}:{port + MAVLINK_PORT_STEP * i}"))
                say(f"gcs: {drone}'s MAVLink to udp {host}:{port + MAVLINK_PORT_STEP * i} (QGC: a UDP comm link there)")

    def close(self, summary: dict[str, Any] | None = None) -> None:
        for out in self.outs:
            out.close()
        if self.bridge is not None:
            self.bridge.close()
        if self.recorder is not None:
            if summary is not None:
                from zenoh_robot.tools.bag.schemas import jsonable
                self.recorder.metadata["gcs.summary"] = {"json": json.dumps(jsonable(summary), allow_nan=False,
                                                                            default=str)}
            self.recorder.close()
