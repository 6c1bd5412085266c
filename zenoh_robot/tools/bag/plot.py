"""Draw a recorded flight from its MCAP alone: ``python -m zenoh_robot.tools.bag.plot flight.mcap out.png``.

Vehicle positions come from the JSON of every ``*/state`` topic with a ``position``
(local NED), setpoints from every ``*Setpoint`` topic (position targets only). Top view
(east/north) and altitude over time. Needs matplotlib (the ``tools`` extra).
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from .info import Record, iter_records


def load(path: str | Path) -> tuple[dict[str, list[tuple[float, float, float, float]]],
                                     dict[str, list[tuple[float, float, float, float]]]]:
    """(states, setpoints): topic -> [(t s, north, east, down)], t from the first message."""
    states: dict[str, list[tuple[float, float, float, float]]] = {}
    setpoints: dict[str, list[tuple[float, float, float, float]]] = {}
    t0: int | None = None
    for rec in iter_records(path):
        if not isinstance(rec, Record) or rec.channel.message_encoding != "json":
            continue
        t0 = rec.message.log_time if t0 is None else t0
        t = (rec.message.log_time - t0) / 1e9
        type_name = rec.channel.metadata.get("zr.type", "")
        try:
            data = json.loads(rec.message.data)
        except ValueError:
            continue
        if isinstance(data.get("position"), list) and len(data["position"]) == 3:
            n, e, d = data["position"]
            if None not in (n, e, d):
                states.setdefault(rec.channel.topic, []).append((t, n, e, d))
        elif type_name.endswith("Setpoint") and not data.get("is_velocity"):
            xyz = (data.get("x"), data.get("y"), data.get("z"))
            if all(isinstance(v, (int, float)) and math.isfinite(v) for v in xyz):
                setpoints.setdefault(rec.channel.topic, []).append((t, *xyz))
    return states, setpoints


def plot(path: str | Path, out: str | Path, title: str | None = None) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    states, setpoints = load(path)
    # Setpoints of the recorded vehicles only (a recording of a shared network holds others' topics).
    spaces = {t.rsplit("/", 1)[0] for t in states}
    setpoints = {t: p for t, p in setpoints.items() if t.rsplit("/", 1)[0] in spaces}
    fig, (top, alt) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1, 1.4]})
    for topic, pts in setpoints.items():
        top.plot([p[2] for p in pts], [p[1] for p in pts], "x", ms=3, alpha=0.5, color="tab:orange",
                 label=f"setpoints {topic}")
        alt.plot([p[0] for p in pts], [-p[3] for p in pts], "x", ms=3, alpha=0.5, color="tab:orange",
                 label=f"setpoint altitude {topic}")
    for topic, pts in states.items():
        top.plot([p[2] for p in pts], [p[1] for p in pts], "-", lw=1.5, color="tab:blue", label=f"vehicle {topic}")
        alt.plot([p[0] for p in pts], [-p[3] for p in pts], "-", lw=1.5, color="tab:blue",
                 label=f"vehicle altitude {topic}")
    top.set_xlabel("east, m")
    top.set_ylabel("north, m")
    top.set_aspect("equal", adjustable="datalim")
    top.grid(alpha=0.3)
    top.legend(fontsize=7, loc="best")
    top.set_title("top view (local NED from PX4)")
    alt.set_xlabel("time since the recording started, s")
    alt.set_ylabel("altitude above home, m")
    alt.grid(alpha=0.3)
    alt.legend(fontsize=7, loc="best")
    alt.set_title("altitude")
    fig.suptitle(title or f"{Path(path).name}: drawn from the MCAP alone")
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zenoh_robot.tools.bag.plot", description=__doc__)
    p.add_argument("mcap")
    p.add_argument("out")
    p.add_argument("--title")
    args = p.parse_args(argv)
    print(plot(args.mcap, args.out, args.title))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
