"""A scripted flight: wait for the drone, OFFBOARD, arm, fly the pattern, land.

Setpoints stream from the GCS's timer the whole time (hover target first), so
PX4's rule that OFFBOARD needs a setpoint stream beforehand is met by the
companion receiving them; commands go through the drone's command service and
are retried, because on a lossy link a request or its reply can be lost.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from .app import Gcs


def _until(pred: Callable[[], bool], timeout: float, step: float = 0.1) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return pred()


def run_mission(gcs: Gcs, drone_id: str, duration: float, log: Callable[..., None]) -> dict[str, Any]:
    out: dict[str, Any] = {"ok": False, "steps": []}
    drone = gcs.add_drone(drone_id)

    def step(name: str, ok: bool, detail: str = "") -> bool:
        out["steps"].append({"step": name, "ok": ok, "detail": detail, "t": time.time()})
        log(f"mission: {name}: {'ok' if ok else 'FAILED'} {detail}")
        return ok

    def command(name: str, value: float = 0.0, tries: int = 3) -> bool:
        res = None
        for _ in range(tries):
            res = drone.command(name, value)
            if res.success:
                break
            time.sleep(0.5)
        assert res is not None
        return step(name, res.success, res.message)

    gcs.restart_pattern(flying=False)
    if not step("drone connected", _until(lambda: bool(drone.state and drone.state.connected), 30.0)):
        return out
    if not command("offboard_start"):
        return out
    if not command("arm"):
        return out
    alt = gcs.config.altitude
    step("climb", _until(lambda: bool(drone.state and -drone.state.position[2] > 0.8 * alt), 20.0))
    gcs.restart_pattern(flying=True)
    log(f"mission: flying the {gcs.config.pattern} pattern for {duration:.0f} s")
    end = time.monotonic() + duration
    while time.monotonic() < end:
        time.sleep(0.2)
    gcs.freeze()
    if not command("land"):
        return out
    landed = _until(lambda: bool(drone.state and drone.state.landed and not drone.state.armed), 30.0)
    step("landed and disarmed", landed)
    out["ok"] = landed
    out["max_path_error_m"] = drone.max_path_error
    return out
