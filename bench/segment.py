#!/usr/bin/python3
"""texsyn segment's accuracy and time on two cases, as in seed 002 §5.2.3
(Fig. 5.11-5.14: single level 72.1 %, multi-scale 80.5 %, multi-scale with
noise reduction 95.8 %, single level with noise reduction 97.7 %):

  collage   the test's collage (tests/integration/test_segment.py) at twice
            its size, 512x512: every picture resized x2 first (brick 400,
            grass 1024, aero1.jpg 1280x960), the same crops and shapes at
            twice the coordinates - a grass background, a brick disk, a
            forest triangle and a town L, each class trained on another
            part of its picture;
  texbynum  ../shared/data/texbynum/source_photo.png (320x462): its
            source_segment.png is no label raster (a colour guide: red sea,
            green rock, a blue-to-black sky gradient, soft edges), so each
            pixel's class is its strongest channel; trained on the left
            half, segmenting the right half, in luminance and in colour.

Each case runs with one level and with the default three, both with
--denoise (the noise reduction of the same run gives the "before" and
"after" figures), with 2 threads. Writes bench/results/segment.{md,json}
and the pictures bench/results/segment-*.png (the label rasters scaled to
be seen).
Usage: bench/segment.py --build BUILD [--out DIR] [--quick]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
sys.path.insert(0, str(REPO / "tests" / "integration"))
from collage import Source, TextureClass, build, disk, ell, oiiotool, read_pnm, triangle, write_pngs  # noqa: E402

THREADS = 2
LEVELS = (1, 3)
NAMES = {"collage": ["brick", "grass", "forest", "town"], "texbynum": ["sea", "rock", "sky"]}


def cpu():
    """The model name, with the family and model numbers (a cloud CPU's
    name can hide its generation)."""
    info = {}
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        key, _, value = line.partition(":")
        info.setdefault(key.strip(), value.strip())
    return f"{info.get('model name', 'unknown')} (family {info.get('cpu family', '?')}, model {info.get('model', '?')})"


def scaled(box, k):
    """A crop WxH+X+Y at k times the size."""
    size, x, y = box.split("+")
    w, h = size.split("x")
    return f"{int(w) * k}x{int(h) * k}+{int(x) * k}+{int(y) * k}"


def collage(out, k):
    """The test's collage at k times its size (k = 1: the test's)."""
    aero = Source(DATA / "aerial/aero1.jpg", f"{640 * k}x{480 * k}" if k > 1 else None)
    classes = [
        TextureClass("brick", 0, Source(DATA / "textures/brick.png", f"{200 * k}x{200 * k}"), scaled("96x96+0+0", k),
                     scaled("96x96+104+104", k)),
        TextureClass("grass", 1, Source(DATA / "textures/grass.png", f"{512 * k}x{512 * k}" if k > 1 else None),
                     scaled("192x192+0+0", k), scaled("256x256+256+256", k)),
        TextureClass("forest", 2, aero, scaled("80x56+64+420", k), scaled("64x56+512+312", k)),
        TextureClass("town", 3, aero, scaled("128x64+110+105", k), scaled("128x80+0+110", k)),
    ]
    layout = [1, (0, disk(0.25, 0.25, 0.18)), (2, triangle((0.68, 0.08), (0.92, 0.08), (0.92, 0.29))),
              (3, ell(0.3, 0.62, 0.79, 0.92, 0.12))]
    return build(classes, layout, 256 * k, out)


def texbynum(out):
    """Training: the photo's left half with the guide's strongest channel as
    class (0 red sea, 1 green rock, 2 blue sky); input: the right half."""
    ppm = out / "guide.ppm"
    oiiotool(DATA / "texbynum/source_segment.png", "-d", "uint8", "-o", ppm)
    w, h, _, px = read_pnm(ppm)
    labels = bytes(max(range(3), key=lambda c: px[3 * i + c]) for i in range(w * h))
    half = w // 2
    left = b"".join(labels[y * w:y * w + half] for y in range(h))
    right = b"".join(labels[y * w + half:(y + 1) * w] for y in range(h))
    write_pngs([(out / "labels0.png", half, h, left), (out / "truth.png", w - half, h, right)])
    photo = DATA / "texbynum/source_photo.png"
    oiiotool(photo, "--cut", f"{half}x{h}+0+0", "-o", out / "train0.png")
    oiiotool(photo, "--cut", f"{w - half}x{h}+{half}+0", "-o", out / "input.png")
    return {"train": [out / "train0.png"], "labels": [out / "labels0.png"], "input": out / "input.png",
            "truth": out / "truth.png"}


def segment(build_dir, p, out, levels, denoise, *extra):
    """One run: its report, and its wall seconds."""
    report = Path(str(out) + ".json")
    cmd = [build_dir / "texsyn", "segment", "--quiet", "--embedded", "--threads", THREADS]
    for t, l in zip(p["train"], p["labels"]):
        cmd += ["--train", t, "--labels", l]
    cmd += ["--input", p["input"], "-o", out, "--truth", p["truth"], "--report", report, "--levels", levels,
            "--denoise", denoise, *extra]
    t0 = time.monotonic()
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    wall = time.monotonic() - t0
    if r.returncode != 0:
        sys.exit(f"bench: {' '.join(map(str, cmd))} failed:\n{r.stderr}")
    return json.loads(report.read_text()), wall


def picture(src, dst, levels_scale=80):
    """A label raster made visible (classes 0..3 times 80)."""
    oiiotool(src, "--mulc", levels_scale, "-d", "uint8", "-o", dst)


def accuracy_rows(rep):
    acc = rep["accuracy"]
    before = [c.get("before") for c in acc["classes"]] + [acc["overall"]["before"]]
    after = [c.get("after") for c in acc["classes"]] + [acc["overall"]["after"]]
    return before, after


def run_case(name, p, build_dir, out, denoise, extra=(), tag=None):
    tag = tag or name
    rows, runs = [], {}
    for levels in LEVELS:
        rep, wall = segment(build_dir, p, out / f"segment-{tag}-L{levels}.png", levels, denoise, *extra)
        before, after = accuracy_rows(rep)
        label = "single level" if levels == 1 else f"multi-scale ({levels} levels)"
        rows.append((label, before))
        rows.append((label + f" + noise reduction ({denoise})", after))
        runs[f"L{levels}"] = {"wall_seconds": wall, "report": rep}
    return {"case": tag, "denoise": denoise, "rows": [{"run": r, "accuracy": a} for r, a in rows], "runs": runs}


def percent(v):
    return "-" if v is None else f"{100 * v:.1f}"


def markdown(res, machine):
    lines = ["# texsyn segment: accuracy and time", "",
             f"Measured {res['date']} on {machine['cpu']}, {machine['cores']} cores, {THREADS} threads; load average "
             f"{machine['load_before']:.2f} before and {machine['load_after']:.2f} after "
             f"({'busy: other work shared the cores' if machine['busy'] else 'idle'}). Every figure is exact search "
             "(no lossy shortcut): the same bytes on any machine, so the accuracies are reproducible; the seconds "
             "are this machine's.", ""]
    lines += ["Seed 002 §5.2.3 (Brodatz collage, 9x9 window): single level 72.1 %, + noise reduction 97.7 %; "
              "multi-scale 80.5 %, + noise reduction 95.8 %.", ""]
    for case in res["cases"]:
        names = NAMES[case["case"].split("-")[0]]
        lines += [f"## {case['case']}", "", case["about"], ""]
        lines += ["| run | " + " | ".join(names) + " | overall |", "|---" * (len(names) + 2) + "|"]
        for row in case["rows"]:
            lines.append(f"| {row['run']} | " + " | ".join(percent(v) for v in row["accuracy"]) + " |")
        lines += ["", "| levels | wall s | per level (coarsest first): size, seconds (self-segmentation part) |",
                  "|---|---|---|"]
        for key, run in case["runs"].items():
            rep = run["report"]
            per = "; ".join(f"{lv['size'][0]}x{lv['size'][1]} {lv['seconds']:.2f} s ({lv['self_seconds']:.2f})"
                            for lv in rep["levels"])
            lines.append(f"| {rep['params']['levels']} | {run['wall_seconds']:.1f} | {per} |")
        multi = case["runs"].get(f"L{LEVELS[-1]}")
        if multi:
            lines += ["", "Level weights w_l^k from the self-segmentation (rows: levels, coarsest first; columns: "
                      "classes):", "", "| level | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
            for lv in multi["report"]["levels"]:
                lines.append(f"| {lv['level']} | " + " | ".join(f"{w:.3f}" for w in lv["weight"]) + " |")
        lines.append("")
    lines += ["Pictures: `segment-*-input.png`, `segment-*-truth.png` and the label rasters of each run "
              "(`segment-CASE-L1.png`: one level, `-L3`: three levels, both after noise reduction), "
              "classes scaled x80 to be seen.", ""]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--quick", action="store_true", help="the test's 256x256 collage instead of 512x512")
    a = ap.parse_args()
    build_dir, out = Path(a.build).resolve(), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="texsyn-segment-") as tmp:
        measure(build_dir, out, Path(tmp), 1 if a.quick else 2)
    print((out / "segment.md").read_text())


def measure(build_dir, out, work, k):
    """Both cases in work (a temporary directory); results and pictures
    into out."""
    load_before = os.getloadavg()[0]
    cases = []
    (work / "collage").mkdir(exist_ok=True)
    (work / "texbynum").mkdir(exist_ok=True)
    p = collage(work / "collage", k)
    c = run_case("collage", p, build_dir, work, 300 * k * k)
    c["about"] = (f"{256 * k}x{256 * k}: grass around a brick disk, a forest triangle and a town L; training "
                  f"crops brick {96 * k}x{96 * k}, grass {192 * k}x{192 * k}, forest {80 * k}x{56 * k}, town "
                  f"{128 * k}x{64 * k}.")
    cases.append(c)
    t = texbynum(work / "texbynum")
    for extra, tag in (((), "texbynum"), (("--rgb-search",), "texbynum-rgb")):
        c = run_case("texbynum", t, build_dir, work, 200, extra, tag)
        c["about"] = ("source_photo.png's left half (160x462) trained with source_segment.png's strongest channel "
                      "as class, its right half segmented" + (", colour windows (--rgb-search)." if extra else
                                                               ", luminance windows."))
        cases.append(c)
    load_after = os.getloadavg()[0]
    machine = {"cpu": cpu(), "cores": os.cpu_count(), "load_before": load_before, "load_after": load_after,
               "busy": max(load_before, load_after) > 0.5}
    res = {"date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()), "machine": machine, "threads": THREADS,
           "cases": cases}
    (out / "segment.json").write_text(json.dumps(res, indent=1) + "\n")
    (out / "segment.md").write_text(markdown(res, machine))
    # The pictures: inputs, truths and outputs, label rasters made visible.
    for case, src in (("collage", p), ("texbynum", t)):
        oiiotool(src["input"], "-o", out / f"segment-{case}-input.png")
        picture(src["truth"], out / f"segment-{case}-truth.png")
    for c in cases:
        for levels in LEVELS:
            picture(work / f"segment-{c['case']}-L{levels}.png", out / f"segment-{c['case']}-L{levels}.png")


if __name__ == "__main__":
    main()
