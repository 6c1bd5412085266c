"""The re-dial repro (docs/lossy-link.md, "A unicast link under loss"): the resilient profile's unicast session
(`stream_profile("resilient").session_config()`, the GCS listening on udp+tcp, the drone a peer dialling both)
in two network namespaces, uniform loss on after 4 s of set-up, Zenoh's debug log per side.

    sudo .venv/bin/python docs/results/lossy/unicast-2026-11-25/redial/run.py LOSS SECONDS TAG [old|new]

`old` strips the per-endpoint re-dial keys (the settings flown on 2026-11-24); `new` is the product as is.
Writes TAG-{gcs,drone}.{json,arr,log} and TAG-meta.json here; gaps.py TAG prints the silences."""
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[4]))
from drone_contract.streams import stream_profile  # noqa: E402
from drone_lab.experiment.netns import LossyLink  # noqa: E402

loss, dur, tag = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
mode = sys.argv[4] if len(sys.argv) > 4 else "new"
env = dict(os.environ, RUST_LOG="zenoh_transport=debug,zenoh::net::runtime=debug,zenoh_link_udp=debug,"
                                "zenoh_link_tcp=debug")
with LossyLink(loss_pct=0) as link:
    base = dataclasses.replace(stream_profile("resilient").session_config(), multicast_scouting=False,
                               shared_memory=False)
    eps = [f"udp/{link.addr('gcs')}:7447", f"tcp/{link.addr('gcs')}:7447"]
    cfgs = {"gcs": dataclasses.replace(base, listen=eps).to_json5(),
            "drone": dataclasses.replace(base, listen=[], connect=eps).to_json5()}
    procs = {}
    for side, c in cfgs.items():
        if mode == "old":
            c["connect"]["endpoints"] = [e.split("#")[0] for e in c["connect"]["endpoints"]]
        path = HERE / f"{tag}-{side}.json"
        path.write_text(json.dumps(c))
        procs[side] = subprocess.Popen(link.exec_in(side) + [sys.executable, str(HERE / "side.py"), side, str(path),
                                                             str(dur + 8)],
                                       stdout=open(HERE / f"{tag}-{side}.log", "w"), stderr=subprocess.STDOUT, env=env)
        time.sleep(0.5)
    time.sleep(4)
    t0 = time.time()
    link.set_loss(loss)
    time.sleep(dur)
    link.set_loss(0)
    for p in procs.values():
        p.wait(timeout=30)
    (HERE / f"{tag}-meta.json").write_text(json.dumps({"t0": t0, "dur": dur, "loss": loss, "mode": mode}))
