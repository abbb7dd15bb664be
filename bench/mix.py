#!/usr/bin/python3
"""Texture mixing across levels (--ref-fine/--mix-level, seed 002 §4.3):
pictures from the shared textures, and what the fine levels cost from a
crop against the whole reference.

mix-brick.png, left to right (384x384, L=5, parity, seed 1): synthesis from
the whole brick.png (512x512); levels 2..4 from the whole brick.png and
levels 1, 0 from a 160x160 crop of it, coarse weight 1 and 4; synthesis
from the crop alone (L=4).

mix-aerial.png: the aerial photograph aero1.jpg (640x480, colour) shrunk
to the output size; synthesis from it (480x360, L=4, colour search); the
same with levels 1, 0 from a 240x180 crop of a built-up area (coarse weight
4): the layout of the photograph, the pixels of the crop.

mix.md: per level, seconds and reference size of the plain run and of the
mixed one (embedded, 2 threads).
"""
import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))


def run(args):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"bench: {' '.join(map(str, args))} failed:\n{p.stderr}")


def synth(exe, tmp, name, ref, size, *extra):
    out, rep = tmp / f"{name}.png", tmp / f"{name}.json"
    run([exe, "synth", "--embedded", "--ref", ref, "-o", out, "--size", size, "--quiet", "--threads", 2,
         "--report", rep, *extra])
    return out, json.loads(rep.read_text())


def mosaic(images, n, out):
    run(["oiiotool", *images, "--mosaic:pad=8", f"{n}x1", "-o", out])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--quick", action="store_true")  # accepted like the other benchmarks; nothing to shorten
    a = ap.parse_args()
    exe, out = Path(a.build) / "texsyn", Path(a.out)
    tmp = out / "tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    brick, aerial = DATA / "textures" / "brick.png", DATA / "aerial" / "aero1.jpg"
    crop, acrop = tmp / "brick-crop160.png", tmp / "aerial-crop.png"
    run(["oiiotool", brick, "--cut", "160x160+180+180", "-o", crop])
    run(["oiiotool", aerial, "--cut", "240x180+200+150", "-o", acrop])
    job = ["--levels", 5, "--parity"]
    plain, plain_rep = synth(exe, tmp, "brick-plain", brick, "384x384", *job)
    mix1, mix_rep = synth(exe, tmp, "brick-mix1", brick, "384x384", *job, "--ref-fine", crop, "--mix-level", 2)
    mix4, _ = synth(exe, tmp, "brick-mix4", brick, "384x384", *job, "--ref-fine", crop, "--mix-level", 2,
                    "--coarse-weight", 4)
    alone, _ = synth(exe, tmp, "brick-crop", crop, "384x384", "--levels", 4, "--parity")
    mosaic([plain, mix1, mix4, alone], 4, out / "mix-brick.png")
    shrunk = tmp / "aerial-shrunk.png"
    run(["oiiotool", aerial, "--resize", "480x360", "-o", shrunk])
    ajob = ["--levels", 4, "--rgb-search"]
    aplain, _ = synth(exe, tmp, "aerial-plain", aerial, "480x360", *ajob)
    amix, _ = synth(exe, tmp, "aerial-mix", aerial, "480x360", *ajob, "--ref-fine", acrop, "--mix-level", 2,
                    "--coarse-weight", 4)
    mosaic([shrunk, aplain, amix], 3, out / "mix-aerial.png")
    lines = ["# Texture mixing (--ref-fine/--mix-level, seed 002 §4.3)", "",
             "brick.png 512x512 -> 384x384, L=5, parity, embedded, 2 threads; mixed: levels 1 and 0 from a "
             "160x160 crop (--mix-level 2). One run each, on a machine other work may have shared: the seconds "
             "show where the work goes, not a measured speed-up.", "",
             "| level | plain: reference | plain (s) | mixed: reference | mixed (s) |", "|---|---|---|---|---|"]
    for p, m in zip(plain_rep["levels"], mix_rep["levels"]):
        lines.append(f"| {p['level']} | {p['ref'][0]}x{p['ref'][1]} | {p['seconds']:.3f} | {m['from']} "
                     f"{m['ref'][0]}x{m['ref'][1]} | {m['seconds']:.3f} |")
    lines += [f"| total | | {plain_rep['seconds']:.3f} | | {mix_rep['seconds']:.3f} |", "",
              "Pictures: `mix-brick.png` (whole reference | mixed, coarse weight 1 | mixed, coarse weight 4 | "
              "the crop alone) and `mix-aerial.png` (the photograph | synthesis from it | mixed with a crop of "
              "a built-up area); see the README, Texture mixing."]
    (out / "mix.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
