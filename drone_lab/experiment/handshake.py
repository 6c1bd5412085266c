"""How long a unicast Zenoh session takes to form across a lossy veth, loss present from start-up.

Each try is a fresh namespace pair: a router listening in the GCS namespace, a node in the drone
namespace opening a session to it (client or peer) and putting a probe every 20 ms. Formation time
is from just before the node's ``zenoh.open`` to the router's first probe (one wall clock: same
host). Tries of one (variant, loss) run side by side in their own namespace pairs, so a cell
costs at most ``--timeout`` seconds. Needs root.

``python -m drone_lab.experiment.handshake --loss 30,50,70,90 --tries 10``
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any

from zenoh_robot.session_config import SessionConfig, fast_open

from .netns import LossyLink

PORT = 7447
PROBE = "hs/probe"
MODULE = "drone_lab.experiment.handshake"


@dataclass(frozen=True)
class Variant:
    name: str
    mode: str                       # the drone side's mode: client (of the router) or peer
    protocols: tuple[str, ...]      # connect order
    keys: dict[str, Any] = field(default_factory=dict, hash=False)
    all_links: bool = False         # a client opening every endpoint (Zenoh's "allOf" group), as the router cell
    shim: bool = False              # UDP through `zenoh-robot linkshim` at both ends (docs/results/linkshim.md)


VARIANTS = {
    # Zenoh 1.10's own timings (10 s open, retries 1 -> 4 s); the client keys only keep open() from failing.
    "zenoh-default": Variant("zenoh-default", "client", ("tcp", "udp"),
                             {"connect/timeout_ms": -1, "connect/exit_on_failure": False}),
    # The unicast transport of the third round: 1 s tries, retries 100 -> 500 ms, TCP listed first.
    "fast-1s-tcp": Variant("fast-1s-tcp", "client", ("tcp", "udp"),
                           fast_open(1000, 100, 500, client=True)),
    # UDP first, 250 ms tries retried after 50 -> 200 ms (session_config.fast_open's defaults).
    "udp-250ms": Variant("udp-250ms", "client", ("udp", "tcp"), fast_open(client=True)),
    # The router cell's companion: a client holding a UDP and a TCP link, open returns once both are up.
    "allof-udp-tcp-250ms": Variant("allof-udp-tcp-250ms", "client", ("udp", "tcp"), fast_open(client=True), True),
    # The same as a peer (the unicast cell): Zenoh connects to every endpoint at once, in the background.
    "peer-udp-250ms": Variant("peer-udp-250ms", "peer", ("udp", "tcp"), fast_open()),
    # A client with one UDP link through the repeating shim: the handshake's datagrams are sent K times.
    "shim-udp-250ms": Variant("shim-udp-250ms", "client", ("udp",), fast_open(client=True), shim=True),
}
SHIM_LOCAL = 7448       # the drone end's port on the drone's loopback (Zenoh connects to it)
SHIM_WIRE = 7449        # the ground end's port on the lossy link


def shim_cmds(router_addr: str) -> dict[str, list[str]]:
    """The two shim ends, per namespace side: the ground end forwards to the router's UDP endpoint."""
    cli = [sys.executable, "-m", "zenoh_robot.tools.cli.linkshim"]
    return {"gcs": cli + ["ground", "--listen", f"{router_addr}:{SHIM_WIRE}", "--target", f"{router_addr}:{PORT}"],
            "drone": cli + ["drone", "--listen", f"127.0.0.1:{SHIM_LOCAL}", "--peer", f"{router_addr}:{SHIM_WIRE}"]}


def start_shims(link: LossyLink) -> list[subprocess.Popen[str]]:
    """Both ends, each waited for until it listens."""
    procs = []
    for side, cmd in shim_cmds(link.addr("gcs")).items():
        p = subprocess.Popen(link.exec_in(side) + cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        procs.append(p)
        while p.stdout is not None and (line := p.stdout.readline()) and "listening" not in line:
            pass
    return procs


def node_config(variant: Variant, router_addr: str) -> SessionConfig:
    endpoints = [f"{p}/{router_addr}:{PORT}" for p in variant.protocols]
    if variant.shim:
        endpoints = [f"udp/127.0.0.1:{SHIM_LOCAL}"]
    extra = dict(variant.keys)
    if variant.all_links:
        extra["connect/endpoints"] = [{"strategy": "allOf", "locators": endpoints}]
    return SessionConfig(mode=variant.mode, listen=[], connect=endpoints, multicast_scouting=False,
                         shared_memory=False, batch_size=1300, lease_s=10.0, keep_alive=100, extra=extra)


def router_config(addr: str) -> SessionConfig:
    return SessionConfig(mode="router", listen=[f"udp/{addr}:{PORT}", f"tcp/{addr}:{PORT}"],
                         multicast_scouting=False, shared_memory=False, batch_size=1300, lease_s=10.0,
                         keep_alive=100, extra=fast_open())


def _router_main(addr: str, timeout: float) -> None:
    import threading

    import zenoh
    got = threading.Event()
    first: list[float] = []

    def on(sample: zenoh.Sample) -> None:
        if not first:
            first.append(time.time())
            first.append(float(sample.payload.to_bytes().decode()))
            got.set()
    s = zenoh.open(router_config(addr).to_zenoh())
    s.declare_subscriber(PROBE, on)
    print("READY", flush=True)
    got.wait(timeout)
    print(json.dumps({"formed_s": first[0] - first[1] if first else None}), flush=True)
    os._exit(0)     # close() can wait on a half-done handshake: the figure is out, nothing to flush


def _node_main(variant: str, router_addr: str, timeout: float) -> None:
    import zenoh
    conf = node_config(VARIANTS[variant], router_addr).to_zenoh()
    t0 = time.time()
    s = zenoh.open(conf)            # a client blocks here until its session is up
    print(json.dumps({"open_s": time.time() - t0}), flush=True)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        s.put(PROBE, repr(t0).encode())
        time.sleep(0.02)


def measure(variant: str, loss: float, tries: int, timeout: float) -> list[float | None]:
    """Formation seconds per try (None: not within ``timeout``)."""
    links = [LossyLink(loss_pct=loss) for _ in range(tries)]
    routers: list[subprocess.Popen[str]] = []
    nodes: list[subprocess.Popen[str]] = []
    shims: list[subprocess.Popen[str]] = []
    try:
        for link in links:
            link.up()
        if VARIANTS[variant].shim:     # before the routers: a router's wait starts at its launch
            shims.extend(p for link in links for p in start_shims(link))
        for link in links:
            me = [sys.executable, "-m", MODULE]
            routers.append(subprocess.Popen(link.exec_in("gcs") + me + ["router", link.addr("gcs"), str(timeout)],
                                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True))
        for r, link in zip(routers, links, strict=True):
            while r.stdout is not None and (line := r.stdout.readline()) and line.strip() != "READY":
                pass
            nodes.append(subprocess.Popen(link.exec_in("drone") + [sys.executable, "-m", MODULE, "node", variant,
                                          link.addr("gcs"), str(timeout + 5)],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True))
        out: list[float | None] = []
        for r, n in zip(routers, nodes, strict=True):
            text, _ = r.communicate(timeout=timeout + 30)
            n.kill()
            n.wait()
            formed: float | None = None
            for line in text.splitlines():
                if line.startswith("{"):
                    formed = json.loads(line).get("formed_s")
            out.append(formed)
        return out
    finally:
        for shim in shims:
            shim.terminate()
            try:
                shim.wait(timeout=5)
            except subprocess.TimeoutExpired:
                shim.kill()
                shim.wait()
        for p in (*routers, *nodes):
            if p.poll() is None:
                p.kill()
                p.wait()
        for link in links:
            link.down()


def summary(times: list[float | None], timeout: float) -> dict[str, Any]:
    ok = sorted(t for t in times if t is not None)
    return {"tries": len(times), "formed": len(ok), "timeout_s": timeout,
            "median_s": statistics.median(ok) if ok else math.nan, "max_s": max(ok) if ok else math.nan,
            "times_s": [None if t is None else round(t, 2) for t in times]}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "router":
        _router_main(argv[1], float(argv[2]))
        return 0
    if argv and argv[0] == "node":
        _node_main(argv[1], argv[2], float(argv[3]))
        return 0
    p = argparse.ArgumentParser(prog="handshake", description=__doc__.splitlines()[0])
    p.add_argument("--loss", default="30,50,70,90")
    p.add_argument("--variants", default="udp-250ms")
    p.add_argument("--tries", type=int, default=10)
    p.add_argument("--timeout", type=float, default=30.0)
    p.add_argument("--out", default=None, help="append one JSON line per (variant, loss)")
    args = p.parse_args(argv)
    for variant in args.variants.split(","):
        for loss in (float(x) for x in args.loss.split(",")):
            row = {"variant": variant, "loss": loss, **summary(measure(variant, loss, args.tries, args.timeout),
                                                               args.timeout)}
            print(json.dumps(row), flush=True)
            if args.out:
                with open(args.out, "a") as f:
                    f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
