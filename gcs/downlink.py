"""Downlink rates: ask each drone, when it joins, for the sensor and camera rates this GCS wants.

A companion publishes SensorCombined at ``sensor_rate_hz`` (200 Hz asked of PX4) and camera
frames at ``camera_rate_hz`` (30) whatever its GCS needs; a swarm GCS that shows ten drones
does not need 200 Hz of IMU or 30 fps from each. With ``--sensor-rate`` / ``--camera-rate``
the GCS sets those two live parameters on ``/<drone>/companion`` (the same parameter service
``zenoh-robot param set`` uses) once per join, and only on a drone it controls: the rates are
every GCS's downlink, so the companion accepts them only from the GCS in control (companion/
params.py). A monitoring GCS says once "not in control: downlink left as is" and asks as soon
as a state shows it in control.

A join is the first state heard from a drone, a state after ``REJOIN_S`` of silence, or a state
showing a sensor rate other than the one applied (the companion restarted with its defaults).
Every outcome is reported once per join: applied (log), refused or unanswered (log warning and
the drone's ``failures``, which the dashboard shows); a failed request is asked again at the
next join, never in a loop. Each rate is set on its own (as ``param set``): a refused one is
named, and one applied beside it is said to be. Calls block, so they run on one worker thread, never the executor.

A drone's own rates can be lowered beside the GCS's (``lower``: gcs/decimation.py, the sensor decimated at
its source when this GCS cannot keep up); they are asked at once and at every later join, and put back to
what the drone had when the GCS releases control or closes.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from zenoh_robot.parameters import Parameter, ParameterType
from zenoh_robot.parameters.client import ParameterClient

if TYPE_CHECKING:
    from zenoh_robot import Node

log = logging.getLogger("gcs.downlink")
NOT_IN_CONTROL = "not in control: downlink left as is"
REJOIN_S = 3.0       # a state after this much silence is a (re)join: ask again
RECHECK_S = 5.0      # at most one "rate differs from the one applied" re-ask per drone per this
CALL_TIMEOUT_S = 3.0
RESTORE_S = 3.0      # closing puts lowered rates back within this (a drone gone must not hold the GCS's exit)
PARAMS = {"sensor_rate_hz": "sensor", "camera_rate_hz": "camera"}


@dataclass
class DownlinkStatus:
    """One drone's answer to the rates asked (what the summary and the sweep report)."""
    status: str = "pending"        # pending | asking | applied | refused | unanswered | not_in_control
    detail: str = ""
    asked: int = 0                 # requests sent (one per join)
    applied_at: float = 0.0
    answers: list[str] = field(default_factory=list)   # every outcome, bounded

    def as_dict(self) -> dict[str, Any]:
        return {"status": self.status, "detail": self.detail, "asked": self.asked, "answers": list(self.answers)}


class DownlinkRates:
    """Sets ``rates`` (companion parameter name -> value) on each drone that joins."""

    MAX_ANSWERS = 10

    def __init__(self, node: Node, rates: dict[str, float], report: Callable[[str, str], None],
                 client_id: str, timeout: float = CALL_TIMEOUT_S) -> None:
        bad = {k: v for k, v in rates.items() if not _valid(k, v)}
        if bad:
            raise ValueError(f"downlink rates: {bad} (sensor_rate_hz, camera_rate_hz > 0)")
        self.node = node
        self.rates = dict(rates)
        self.timeout = timeout
        self.client_id = client_id     # this GCS: sent with the requests, compared with each drone's controller
        self._report = report          # (drone, refusal text): the drone's failures list
        self.status: dict[str, DownlinkStatus] = {}
        self._lowered: dict[str, dict[str, float]] = {}    # drone -> rates lowered for it (lower())
        self._before: dict[str, dict[str, float]] = {}     # drone -> what it had before: restored on close
        self._restored = False                             # restore() ran: nothing is lowered after it
        self._clients: dict[str, ParameterClient] = {}
        self._pending: list[str] = []  # bounded: a drone is at most once in it
        self._recheck_at: dict[str, float] = {}
        self._cv = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="gcs-downlink", daemon=True)
        self._thread.start()

    def rates_for(self, drone: str) -> dict[str, float]:
        """What this GCS asks of ``drone``: its own rates, and any lowered for that drone."""
        with self._cv:
            return {**self.rates, **self._lowered.get(drone, {})}

    def lower(self, drone: str, name: str, value: float, before: float) -> None:
        """Ask ``drone`` for ``name`` = ``value`` now and at every later join (``before``: the drone's value
        now, put back on close). Any thread; the call runs on the worker."""
        if not _valid(name, value):
            raise ValueError(f"downlink rate {name}={value!r}")
        with self._cv:
            if self._restored:
                return        # the GCS is letting go of its drones: what it lowers now would outlive it
            self._lowered.setdefault(drone, {})[name] = float(value)
            if math.isfinite(before) and before > 0:
                self._before.setdefault(drone, {}).setdefault(name, float(before))
        self.joined(drone)

    # -- joins (executor thread: never blocks) ---------------------------------------
    def on_state(self, drone: str, previous_at: float, now: float, sensor_requested_hz: float,
                 controller: str) -> None:
        """Called with every state (``controller``: the state's GCS in control): decides whether
        this is a join worth asking at."""
        if not self.rates_for(drone):
            return        # nothing to ask of this drone (a GCS that only lowers rates when it must)
        if controller != self.client_id:
            self._not_in_control(drone)
            return
        st = self.status.get(drone)
        if st is None or st.status == "not_in_control" or previous_at == 0.0 or now - previous_at > REJOIN_S:
            self.joined(drone)
            return
        want = self.rates_for(drone).get("sensor_rate_hz")
        # Restarted within REJOIN_S: its state shows its default rate again.
        if (st.status == "applied" and want is not None and math.isfinite(sensor_requested_hz)
                and abs(sensor_requested_hz - want) > 1e-3 and now >= self._recheck_at.get(drone, 0.0)):
            self._recheck_at[drone] = now + RECHECK_S
            self.joined(drone)

    def _not_in_control(self, drone: str) -> None:
        with self._cv:
            st = self.status.setdefault(drone, DownlinkStatus())
            if st.status in ("not_in_control", "asking") or drone in self._pending:
                return   # said once; a request already under way is answered by the companion
            st.status, st.detail = "not_in_control", NOT_IN_CONTROL
            st.answers.append(NOT_IN_CONTROL)
            del st.answers[:-self.MAX_ANSWERS]
        log.warning("%s: %s (asked when this GCS is in control)", drone, NOT_IN_CONTROL)

    def joined(self, drone: str) -> None:
        with self._cv:
            st = self.status.setdefault(drone, DownlinkStatus())
            if drone in self._pending or st.status == "asking":
                return
            st.status = "pending"
            self._pending.append(drone)
            self._cv.notify()

    # -- requests (worker thread) ----------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._pending and not self._stop:
                    self._cv.wait()
                if self._stop:
                    return
                drone = self._pending.pop(0)
                st = self.status[drone]
                st.status, st.asked = "asking", st.asked + 1
            rates = self.rates_for(drone)
            status, detail = self._ask(drone, rates)
            with self._cv:
                st.status, st.detail = status, detail
                if status == "applied":
                    st.applied_at = time.monotonic()
                st.answers.append(f"{status}: {detail}" if detail else status)
                del st.answers[:-self.MAX_ANSWERS]
                if self._lowered.get(drone, {}).items() - rates.items() and drone not in self._pending:
                    self._pending.append(drone)     # lowered while this ask was under way: ask for that too
            asked = ", ".join(f"{PARAMS[k]} {v:g} Hz" for k, v in rates.items())
            if status == "applied":
                log.info("%s: downlink %s applied", drone, asked)
            else:   # once per join: the next join asks again
                log.warning("%s: downlink %s %s: %s (asked again when it rejoins)", drone, asked, status, detail)
                self._report(drone, f"downlink {status}: {detail}")

    def _ask(self, drone: str, rates: dict[str, float]) -> tuple[str, str]:
        try:
            client = self._clients.get(drone)
            if client is None:
                client = self._clients[drone] = ParameterClient(self.node, f"/{drone}/companion", self.timeout,
                                                                          self.client_id)
            params = [Parameter(k, ParameterType.DOUBLE, float(v)) for k, v in rates.items()]
            results = client.set(params)
        except Exception as exc:   # timeout, no server, a closing session: reported, never raised
            return "unanswered", f"{type(exc).__name__}: {exc}"[:200]
        if len(results) != len(params):
            return "refused", f"{len(results)} answers for {len(params)} parameters"
        # Each parameter is set on its own (rclpy's set_parameters): say which were applied and which not.
        refused = [r.reason if p.name in r.reason else f"{p.name}: {r.reason or 'refused'}"
                   for p, r in zip(params, results, strict=True) if not r.successful]
        if refused:
            applied = [p.name for p, r in zip(params, results, strict=True) if r.successful]
            return "refused", ("; ".join(refused) + (f" ({', '.join(applied)} applied)" if applied else ""))[:300]
        return "applied", ""

    def close(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=self.timeout + 3.0)
        self.restore()

    def restore(self) -> None:
        """What was lowered goes back to what the drone had: a GCS's overload ends with the GCS (called before
        it releases control: the companion takes rates from its controller only; again on close, a no-op
        then). One try per drone (the session may be closing or the drone gone: said, never raised)."""
        with self._cv:
            self._restored = True
            before = {d: dict(r) for d, r in self._before.items()}
            self._before.clear()
            for drone, rates in before.items():   # else the next state (the rate restored) would re-ask the lower one
                for name in rates:
                    self._lowered.get(drone, {}).pop(name, None)
        end = time.monotonic() + RESTORE_S
        for drone, rates in before.items():
            shown = ", ".join(f"{PARAMS[k]} {v:g} Hz" for k, v in rates.items())
            status, detail = self._ask(drone, rates) if time.monotonic() < end else ("skipped", "closing")
            if status == "applied":
                log.info("%s: downlink %s restored", drone, shown)
            else:
                log.warning("%s: downlink %s not restored (%s: %s); `zenoh-robot param set /%s/companion` sets it",
                            drone, shown, status, detail, drone)


def _valid(name: str, value: float) -> bool:
    return name in PARAMS and math.isfinite(value) and value > 0
