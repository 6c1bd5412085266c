"""Pictures of the GCS dashboard as an operator sees it: ``zenoh-robot demo`` in a tmux pane, the pane
resized to each width while the drone flies, each capture (with its colours) drawn as an SVG.

    python -m drone_lab.dashboard_shots --out docs/dashboard [--widths 80,120,200]

Needs tmux. The pictures are what docs/gcs-dashboard.md shows; re-run after changing gcs/dashboard.py.
"""
from __future__ import annotations

import argparse
import io
import shutil
import subprocess
import sys
import time
from pathlib import Path

SESSION = "zr-dashboard-shots"
HEIGHT = 30
FLYING = "flying the"          # the mission's step line under the table once the pattern starts
TIMEOUT_S = 120.0


def _tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], check=True, capture_output=True, text=True).stdout


def _capture(colours: bool = True) -> str:
    return _tmux("capture-pane", "-t", SESSION, *(["-e"] if colours else []), "-p")


FONT = "/usr/share/fonts/truetype/dejavu/DejaVuSansMono.ttf"


def to_png(plain: str, width: int, path: Path) -> bool:
    """The pane's text as a PNG (black on white, DejaVu Sans Mono): False without the font."""
    from PIL import Image, ImageDraw, ImageFont
    try:
        font = ImageFont.truetype(FONT, 14)
    except OSError:
        return False
    lines = plain.rstrip("\n").split("\n")
    cell_w, cell_h = font.getlength("M"), 18
    img = Image.new("RGB", (int(cell_w * width) + 16, cell_h * len(lines) + 16), "white")
    draw = ImageDraw.Draw(img)
    for i, line in enumerate(lines):
        draw.text((8, 8 + i * cell_h), line, font=font, fill="black")
    img.save(path)
    return True


def to_svg(ansi: str, width: int, title: str) -> str:
    """The pane's text with its colours, drawn by rich as a terminal window of ``width`` columns."""
    from rich.console import Console
    from rich.text import Text
    console = Console(record=True, width=width, file=io.StringIO(), force_terminal=True, color_system="truecolor")
    console.print(Text.from_ansi(ansi.rstrip("\n")), soft_wrap=True)
    return console.export_svg(title=title)


def shoot(out: Path, widths: list[int], duration: float) -> list[Path]:
    if shutil.which("tmux") is None:
        raise SystemExit("dashboard_shots: tmux is not installed (apt-get install tmux)")
    out.mkdir(parents=True, exist_ok=True)
    cli = Path(sys.executable).with_name("zenoh-robot")
    subprocess.run(["tmux", "kill-session", "-t", SESSION], capture_output=True)
    _tmux("new-session", "-d", "-s", SESSION, "-x", str(max(widths)), "-y", str(HEIGHT),
          f"{cli} demo --duration {duration:g}; sleep 30")
    written = []
    try:
        end = time.monotonic() + TIMEOUT_S
        while FLYING not in _capture():
            if time.monotonic() > end:
                raise SystemExit(f"dashboard_shots: the demo did not fly within {TIMEOUT_S:g} s:\n{_capture()}")
            time.sleep(0.5)
        time.sleep(3.0)     # rates over their 3 s window
        for width in widths:
            _tmux("resize-window", "-t", SESSION, "-x", str(width), "-y", str(HEIGHT))
            time.sleep(1.5)     # the dashboard redraws at 4 Hz at the new size
            path = out / f"dashboard-{width}.svg"
            path.write_text(to_svg(_capture(), width, f"zenoh-robot demo, {width} columns"))
            written.append(path)
            png = path.with_suffix(".png")
            if to_png(_capture(colours=False), width, png):
                written.append(png)
            print(f"wrote {path}", flush=True)
    finally:
        # Ctrl-C, as an operator would: the demo stops its processes in order, then the pane goes.
        subprocess.run(["tmux", "send-keys", "-t", SESSION, "C-c"], capture_output=True)
        end = time.monotonic() + 60.0
        while time.monotonic() < end and " s in all" not in _tail() and _alive():
            time.sleep(0.5)
        time.sleep(5.0)
        subprocess.run(["tmux", "kill-session", "-t", SESSION], capture_output=True)
    return written


def _alive() -> bool:
    return subprocess.run(["tmux", "has-session", "-t", SESSION], capture_output=True).returncode == 0


def _tail() -> str:
    try:
        return _capture(colours=False)[-2000:]
    except subprocess.CalledProcessError:
        return ""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m drone_lab.dashboard_shots", description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("docs/dashboard"))
    p.add_argument("--widths", default="80,120,200")
    p.add_argument("--duration", type=float, default=60.0, help="the demo's --duration")
    args = p.parse_args(argv)
    try:
        widths = sorted({int(w) for w in args.widths.split(",") if w})
    except ValueError:
        p.error(f"--widths {args.widths!r}: expected numbers, e.g. 80,120,200")
    shoot(args.out, widths, args.duration)
    return 0


if __name__ == "__main__":
    sys.exit(main())
