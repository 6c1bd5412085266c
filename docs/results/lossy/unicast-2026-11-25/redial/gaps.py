"""Silences over 0.5 s per side of a re-dial repro run (seconds from the loss coming on), and liveliness."""
import json
import lzma
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
tag = sys.argv[1]
t0 = json.loads((HERE / f"{tag}-meta.json").read_text())["t0"]
for side in ("drone", "gcs"):
    ts, liv = [], []
    raw = HERE / f"{tag}-{side}.arr"
    text = raw.read_text() if raw.exists() else lzma.open(f"{raw}.xz", "rt").read()
    for line in text.splitlines():
        p = line.split()
        if p[1] == "LIV":
            liv.append(f"{float(p[0]) - t0:+.1f} {p[2]} {p[3]}")
        else:
            ts.append(float(p[0]))
    gaps = [(b - a, a - t0) for a, b in zip(ts, ts[1:], strict=False) if b - a > 0.5]
    print(f"{side} heard {len(ts)}; silences > 0.5 s: " + ", ".join(f"{t:+.1f} s: {g:.1f} s" for g, t in gaps))
    print("   liveliness:", liv)
