#!/usr/bin/python3
"""A test shot: frames cut from a still photograph under a known camera
motion (a pan plus a slow zoom in), for `texsyn flicker`, `texsyn video`
(issue 27) and their benchmarks. Needs only Debian's python3 and oiiotool.

Frame i (0-based) of N shows the window of the source centred at
    centre(i) = start centre + i * (PAN_X, PAN_Y)     (source pixels)
of size SIZE * SCALE / ZOOM**(i / (N - 1)), cut at whole pixels and
resized to SIZE: the content moves by about PAN / SCALE output pixels a
frame and grows by ZOOM over the shot. The window must stay inside the
source; if it would not, nothing is written and the message says by how
much. One oiiotool process writes every frame.

usage: bench/video_shot.py PATTERN [--frames 48] [--first 1] [--size 256x192]
                           [--pan 2,1] [--zoom 1.15] [--scale 1.5] [--start X,Y]
                           [--source ../shared/data/aerial/aero1.jpg]
PATTERN holds the frame number as %d or %04d, e.g. shot/%04d.png."""
import argparse
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_SOURCE = REPO.parent / "shared" / "data" / "aerial" / "aero1.jpg"


def pair(text, kind):
    a, b = text.split(",") if "," in text else text.split("x")
    return kind(a), kind(b)


def source_size(path):
    out = subprocess.run(["oiiotool", "--info", str(path)], capture_output=True, text=True, check=True).stdout
    m = re.search(r":\s*(\d+)\s*x\s*(\d+)", out)
    if not m:
        sys.exit(f"video_shot: cannot read the size of {path} from oiiotool --info: {out.strip()}")
    return int(m.group(1)), int(m.group(2))


def windows(args, src_w, src_h):
    """Every frame's source window (w, h, x, y), whole pixels."""
    w, h = args.size
    cx, cy = args.start if args.start else (src_w / 2 - args.pan[0] * (args.frames - 1) / 2,
                                            src_h / 2 - args.pan[1] * (args.frames - 1) / 2)
    out = []
    for i in range(args.frames):
        t = i / (args.frames - 1) if args.frames > 1 else 0.0
        s = args.scale / args.zoom ** t
        ww, wh = round(w * s), round(h * s)
        x, y = round(cx + args.pan[0] * i - ww / 2), round(cy + args.pan[1] * i - wh / 2)
        if x < 0 or y < 0 or x + ww > src_w or y + wh > src_h:
            sys.exit(f"video_shot: frame {args.first + i}'s window {ww}x{wh}+{x}+{y} leaves the {src_w}x{src_h} "
                     f"source; give a smaller --pan, --scale or --frames, or another --start")
        out.append((ww, wh, x, y))
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("pattern")
    p.add_argument("--frames", type=int, default=48)
    p.add_argument("--first", type=int, default=1)
    p.add_argument("--size", type=lambda t: pair(t, int), default=(256, 192))
    p.add_argument("--pan", type=lambda t: pair(t, float), default=(2.0, 1.0))
    p.add_argument("--zoom", type=float, default=1.15)
    p.add_argument("--scale", type=float, default=1.5)
    p.add_argument("--start", type=lambda t: pair(t, float), default=None)
    p.add_argument("--source", type=Path, default=DEFAULT_SOURCE)
    args = p.parse_args()
    if args.frames < 1 or args.zoom <= 0 or args.scale <= 0:
        sys.exit("video_shot: --frames must be at least 1, --zoom and --scale above 0")
    if not re.search(r"%0?\d*d", args.pattern):
        sys.exit(f"video_shot: {args.pattern}: put the frame number in the name (%d or %04d)")
    cmd = ["oiiotool", str(args.source)]
    for i, (ww, wh, x, y) in enumerate(windows(args, *source_size(args.source))):
        out = Path(args.pattern % (args.first + i))
        out.parent.mkdir(parents=True, exist_ok=True)
        cmd += ["--dup", "--cut", f"{ww}x{wh}+{x}+{y}", "--resize", f"{args.size[0]}x{args.size[1]}",
                "-o", str(out), "--pop"]
    subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main()
