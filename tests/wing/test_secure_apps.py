"""The real apps under the secure profile: keys, router, companion and GCS as processes, a mission.

Everything the apps need must pass the role ACL and nothing else may: the router runs with
Zenoh's access-control trace on, and every message it drops ("Msg intercepted!", the line
before it names the subject, the action and the key) is collected. The legitimate system may
cause none; the rogue (a valid certificate of another drone, CN=uav2, forging the GCS's client
id) must cause some, which also shows the detection works. Loopback only, free ports.
"""
from __future__ import annotations

import json
import re
import subprocess
import threading
import time
from pathlib import Path

import pytest
import zenoh
from conftest import free_port, python_proc, stop_process, wait_for

from drone_contract.messages import Command, CommandResult, DroneSetpoint  # noqa: E402
from drone_contract.streams import stream_profile  # noqa: E402
from zenoh_robot import Node, ServiceCallError  # noqa: E402
from zenoh_robot.msgs import Header  # noqa: E402
from zenoh_robot.session_config import SessionConfig  # noqa: E402

CLI = ("-m", "zenoh_robot.tools.cli.main")
OP = "op"
# The router CLI with Zenoh's Rust log on stdout: the ACL's decisions at trace level.
ROUTER = ("-c", "import sys, zenoh; zenoh.init_log_from_env_or('error'); "
                "from zenoh_robot.tools.cli.main import main; sys.exit(main(sys.argv[1:]))")
ACL_TRACE = {"RUST_LOG": "zenoh::net::routing::interceptor=trace", "NO_COLOR": "1", "RUST_LOG_STYLE": "never"}
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# One ACL decision: "[Using cached result: ]<zid> [on <subject> ]is [un]authorized to <action> (<flow>) on <key>".
_DECISION = re.compile(r"ThreadId\((?P<thread>\d+)\).*access_control: (?:Using cached result: )?(?P<zid>[0-9a-f]+) "
                       r"(?:on (?P<subject>\S+) )?is (?:un)?authorized to (?P<action>.+?) \((?P<flow>\w+)\) "
                       r"on (?P<key>\S+)")
_DROPPED = re.compile(r"ThreadId\((?P<thread>\d+)\).*Msg intercepted!")
_CN = re.compile(r"CertCommonName\(([^)]+)\)")


def _keys(d: Path) -> None:
    """The operator's commands for router, gcs and uav1 (processes); the test's extra certificates in-process."""
    res = python_proc(*CLI, "keys", "init", str(d)).communicate(timeout=120)[0]
    assert (d / "ca.pem").is_file(), res
    issues = [("router", "--role", "router"), ("gcs", "--role", "gcs", "--drones", "uav1"), ("uav1", "--role", "drone")]
    procs = [python_proc(*CLI, "keys", "issue", *a, "--dir", str(d)) for a in issues]   # at once: roles.yaml is locked
    for proc in procs:
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0, out
    from zenoh_robot.tools import keys
    keys.issue(d, "uav2", "drone")              # the rogue: a valid certificate of another drone
    keys.issue(d, "monitor", "gcs")             # a read-only observer: a GCS commanding no drone
    assert {"router", "gcs", "uav1", "uav2", "monitor"} <= set(keys.load_roles(d))


class RouterLog:
    """The router's output, drained on a thread; the messages its ACL dropped, with the sender's CN.

    Zenoh logs each decision, then "Msg intercepted!" on the same thread when it drops the message;
    cached decisions name only the zid, so the zid's certificate name comes from its first decision.
    """

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self.lines: list[str] = []
        self.denied: list[dict[str, str]] = []
        self._cn: dict[str, str] = {}
        self._last: dict[str, re.Match[str]] = {}
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            line = _ANSI.sub("", raw)
            if (m := _DECISION.search(line)) is not None:
                self._last[m["thread"]] = m
                if m["subject"] and (cn := _CN.search(m["subject"])):
                    self._cn[m["zid"]] = cn.group(1)
            elif (d := _DROPPED.search(line)) is not None:
                last = self._last.get(d["thread"])
                self.denied.append({"cn": self._cn.get(last["zid"], "?"), "action": last["action"], "key": last["key"]}
                                   if last else {"cn": "?", "action": "?", "key": "?"})
            elif "interceptor" not in line:
                self.lines.append(line)


def _stop(proc: subprocess.Popen, timeout: float = 15.0) -> str:
    return stop_process(proc, timeout)


def _client(keys: Path, name: str, endpoint: str) -> SessionConfig:
    return SessionConfig(secure=str(keys), name=name, mode="client", listen=[], connect=[endpoint],
                         multicast_scouting=False)


def test_mission_through_secure_router_and_rogue_drone_is_denied(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    _keys(keys)
    # The apps' own sessions: clients of the router, loopback only (a client listens nowhere useful).
    app_conf = tmp_path / "client.json5"
    app_conf.write_text('{ mode: "client", listen: { endpoints: ["tls/127.0.0.1:0"] }, '
                        'scouting: { multicast: { enabled: false } } }')
    endpoint = f"tls/127.0.0.1:{free_port()}"
    secure = ("--zenoh", str(app_conf), "--secure", str(keys), "--connect", endpoint)
    router = python_proc(*ROUTER, "router", "--secure", str(keys), "--listen", endpoint, "--no-scouting",
                         "--status", "0", "--duration", "120", env=ACL_TRACE)
    log = RouterLog(router)
    record = tmp_path / "companion.json"
    companion = gcs = None
    monitor: zenoh.Session | None = None
    try:
        assert wait_for(lambda: any("listening on" in x for x in log.lines), 20), log.lines[-5:]
        # A read-only observer (a GCS certificate commanding no drone) subscribes to everything, so
        # every stream the apps publish is really routed, and ACL-checked, at the router.
        monitor = zenoh.open(_client(keys, "monitor", endpoint).to_zenoh())
        seen: set[str] = set()
        monitor.declare_subscriber("**", lambda s: seen.add(str(s.key_expr)))
        companion = python_proc("-m", "companion", "--id", "uav1", "--px4", "sim", "--camera-rate", "5",
                                "--record", str(record), *secure)
        assert wait_for(lambda: "uav1/state" in seen, 30), "no state from the secure companion"
        gcs = python_proc("-m", "gcs", "--no-dashboard", "--gcs-id", OP, "--drones", "uav1", "--mission",
                          "--duration", "5", "--pattern", "square", "--size", "4", "--altitude", "2.5", *secure)
        # The GCS's liveliness token passes the router (the companion's control relies on it).
        assert wait_for(lambda: any(str(r.ok.key_expr) == f"zr_gcs/{OP}" for r in
                                    monitor.liveliness().get("zr_gcs/**", timeout=1.0) if r.ok), 30, interval=0.5)
        assert wait_for(lambda: "uav1/setpoint" in seen, 30), "no setpoints from the secure GCS"

        # The rogue: a valid drone certificate (uav2) forging the controlling GCS's client id.
        with Node("rogue", config=_client(keys, "uav2", endpoint)) as rogue:
            qos = stream_profile("resilient").qos["setpoint"]
            pub = rogue.create_publisher(DroneSetpoint, "/uav1/setpoint", qos)
            for _ in range(20):
                pub.publish(DroneSetpoint(Header.now(), OP, 0.0, 0.0, -2.5))
                time.sleep(0.05)
            client = rogue.create_client("/uav1/command", Command, CommandResult)
            with pytest.raises(ServiceCallError):     # no reply: the query never reached the drone
                client.call(Command("land", 0.0, "", False, OP), timeout=1.5)

        out, _ = gcs.communicate(timeout=90)
        assert gcs.returncode == 0 and "mission ok" in out, out
        sent = int(re.search(r"uav1: setpoints sent (\d+)", out).group(1))   # type: ignore[union-attr]
        comp_out = _stop(companion)
        assert "Traceback" not in comp_out, comp_out
        summary = json.loads(record.read_text())
    finally:
        if monitor is not None:
            monitor.close()
        for proc in (gcs, companion):
            if proc is not None and proc.poll() is None:
                _stop(proc)
        _stop(router)

    # Every stream the apps publish was routed: state, sensor, image, events, both sides' statistics.
    for key in ("uav1/state", "uav1/sensor", "uav1/image", "uav1/events", "uav1/setpoint",
                "uav1/statistics/setpoint", "uav1/statistics/sensor"):
        assert key in seen, f"{key} never crossed the secure router; seen {sorted(seen)}"
    # Nothing the legitimate system sent was dropped; the rogue was (and that shows the check works).
    legit = [d for d in log.denied if d["cn"] != "uav2"]
    assert not legit, f"the ACL dropped legitimate traffic: {legit}"
    rogue_denied = {(d["action"], d["key"]) for d in log.denied}
    assert ("Put", "uav1/setpoint") in rogue_denied, rogue_denied
    assert ("Query", "@srv/uav1/command") in rogue_denied, rogue_denied
    # The companion never saw the rogue's setpoints: no more than the GCS sent, none refused.
    assert summary["setpoints"]["received"] <= sent, (summary["setpoints"], sent)
    assert summary["setpoints_rejected"] == 0 and summary["commands_refused"] == 0, summary
