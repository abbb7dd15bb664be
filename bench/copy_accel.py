#!/usr/bin/python3
"""The copy-map shortcut (--copy-accel, seed 002 §3.6.6) on the seed's
Table 3.3 job (brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3, parity
control, embedded, 2 threads): exact and with the shortcut, in alternating
runs, medians per level.

Two settings: the seed's algorithm (the scan alone, --refine 0, as Table
3.3 and bench/table33.py's main columns) and texsyn's default (2
refinement sweeps). Reported per level: seconds exact and with the
shortcut, the speed-up, the share of blocks copied without a search, the
constancy the level measured and the one its decision rested on; for the
whole job: seconds, the share of blocks (and pixels) whose source differs
from the exact run (the --copy-map-raw outputs compared), and the exact
best-match error (texsyn quality) of both images. A run without parity
shows the constancy check keeping the shortcut off (sources oscillate,
regions do not stay constant, §3.3.3).

The machine's load average is recorded before and after: figures taken
while other work ran are marked so.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
JOB = ["--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3, "--threads", 2, "--quiet"]
SEED_TABLE = {1: (35.03, 22.94), 0: (569.13, 259.26)}  # Table 3.3: +MMX, +Copy map (s)


def run(exe, args):
    p = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"bench: texsyn {' '.join(map(str, args))} failed:\n{p.stderr}")
    return p


def synth(exe, tmp, name, extra):
    out, raw, rep = tmp / f"{name}.png", tmp / f"{name}.raw", tmp / f"{name}.json"
    run(exe, ["synth", "--embedded", "--ref", DATA / "textures" / "brick.png", "-o", out, "--copy-map-raw", raw,
              "--report", rep, *JOB, *extra])
    return json.loads(rep.read_text())


def pairs(path):
    raw = path.read_bytes()
    return [raw[i:i + 8] for i in range(0, len(raw), 8)]


def differing(a, b, w=1024, h=1024, wb=3):
    """Shares of pixels and of blocks (their top-left pixel) whose source
    differs between two raw copy maps."""
    pa, pb = pairs(a), pairs(b)
    px = sum(x != y for x, y in zip(pa, pb)) / len(pa)
    tops = [y * w + x for y in range(0, h, wb) for x in range(0, w, wb)]
    blocks = sum(pa[o] != pb[o] for o in tops) / len(tops)
    return px, blocks


def loadavg():
    return float(Path("/proc/loadavg").read_text().split()[0])


def setting(exe, tmp, name, extra, reps):
    """Exact and shortcut runs alternating; medians per level."""
    reports = {"exact": [], "accel": []}
    for _ in range(reps):
        reports["exact"].append(synth(exe, tmp, f"{name}-exact", extra))
        reports["accel"].append(synth(exe, tmp, f"{name}-accel", [*extra, "--copy-accel"]))
    med = {}
    for mode, reps_ in reports.items():
        levels = {lv["level"]: statistics.median(r["levels"][4 - lv["level"]]["seconds"] for r in reps_)
                  for lv in reps_[0]["levels"]}
        med[mode] = {"levels": levels, "total": statistics.median(r["seconds"] for r in reps_)}
    px, blocks = differing(tmp / f"{name}-accel.raw", tmp / f"{name}-exact.raw")
    q = {m: json.loads(run(exe, ["quality", "--ref", DATA / "textures" / "brick.png", "--image",
                                 tmp / f"{name}-{m}.png", "--samples", 3000]).stdout) for m in ("exact", "accel")}
    last = reports["accel"][-1]
    return {"extra": extra, "runs": reps, "exact": med["exact"], "accel": med["accel"],
            "shortcut": last["shortcuts"]["copy_map"], "search": last["search"],
            "differing_pixels": px, "differing_blocks": blocks,
            "quality": {m: {"inner": q[m]["inner_mean"], "seam": q[m]["seam_mean"]} for m in q}}


def level_rows(res):
    rows = []
    for lv in res["shortcut"]["levels"]:
        l = lv["level"]
        e, a = res["exact"]["levels"][l], res["accel"]["levels"][l]
        c = "-" if lv["constancy"] is None else f"{lv['constancy']:.3f}"
        ca = "-" if lv["constancy_above"] is None else f"{lv['constancy_above']:.3f} ({lv['measured_above']})"
        rows.append(f"| {l} | {lv['role']} | {e:.3f} | {a:.3f} | {e / a:.2f}x | {lv['skipped_share']:.3f} | "
                    f"{lv['candidates']} of {lv['blocks']} | {c} | {ca} |")
    return rows


def write(out, results, machine, load):
    busy = load[0] > 0.5  # before: the bench's own 2 threads are in the value after
    lines = ["# Copy-map shortcut (--copy-accel, seed 002 §3.6.6) on the Table 3.3 job", "",
             "brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3, parity control, embedded, 2 threads, "
             f"{machine}. Exact and shortcut runs alternating, medians of {results['seed']['runs']}. "
             f"Load average before/after: {load[0]:.2f}/{load[1]:.2f} (after includes the bench's own 2 threads)"
             + (" - **measured while other work ran on the machine: times are indicative only**." if busy else "."),
             "", "Roles: `none` (no level above to predict from), `measure` (every candidate searched, its "
             "constancy measured), `copy` (candidates copied from their prediction, 1 in 8 still searched to "
             "keep measuring). A level copies once at least 64 candidates were measured above it and kept "
             "their predicted source at a pooled rate of 0.95 or more."]
    for key, title in (("seed", "The seed's algorithm (--refine 0)"), ("default", "texsyn's default (2 sweeps)")):
        r = results[key]
        lines += ["", f"## {title}", "",
                  "| level | role | exact (s) | shortcut (s) | speed-up | blocks copied | candidates | "
                  "constancy | constancy above (measured) |", "|---|---|---|---|---|---|---|---|---|",
                  *level_rows(r),
                  f"| total | | {r['exact']['total']:.3f} | {r['accel']['total']:.3f} | "
                  f"{r['exact']['total'] / r['accel']['total']:.2f}x | | | | |", "",
                  f"Sources differing from the exact run: {100 * r['differing_blocks']:.2f} % of blocks, "
                  f"{100 * r['differing_pixels']:.2f} % of pixels. Exact best-match error of 7x7 windows "
                  f"(grey levels per pixel, texsyn quality): exact {r['quality']['exact']['inner']:.3f} inner / "
                  f"{r['quality']['exact']['seam']:.3f} seam, shortcut {r['quality']['accel']['inner']:.3f} / "
                  f"{r['quality']['accel']['seam']:.3f}."]
    np_ = results["no_parity"]
    lines += ["", "## Without parity control (--refine 0)", "",
              "| level | role | candidates | constancy | constancy above (measured) |", "|---|---|---|---|---|"]
    for lv in np_["shortcut"]["levels"]:
        c = "-" if lv["constancy"] is None else f"{lv['constancy']:.3f}"
        ca = "-" if lv["constancy_above"] is None else f"{lv['constancy_above']:.3f} ({lv['measured_above']})"
        lines.append(f"| {lv['level']} | {lv['role']} | {lv['candidates']} of {lv['blocks']} | {c} | {ca} |")
    lines += ["", f"Search mode: `{np_['search']['mode']}`; sources differing from the exact run: "
              f"{100 * np_['differing_blocks']:.2f} % of blocks (the check kept the shortcut off).", "",
              "Seed (Table 3.3, 2.53 GHz, MMX + parity, then + copy map): level 1 "
              f"{SEED_TABLE[1][0]} -> {SEED_TABLE[1][1]} s ({SEED_TABLE[1][0] / SEED_TABLE[1][1]:.2f}x), level 0 "
              f"{SEED_TABLE[0][0]} -> {SEED_TABLE[0][1]} s ({SEED_TABLE[0][0] / SEED_TABLE[0][1]:.2f}x); the text "
              "says 2x at low levels up to 4x at high ones."]
    (out / "copy-accel.md").write_text("\n".join(lines) + "\n")
    (out / "copy-accel.json").write_text(json.dumps({"machine": machine, "loadavg": load, "busy": busy,
                                                     **results}, indent=1))
    print("\n".join(lines))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    exe = Path(a.build) / "texsyn"
    out = Path(a.out)
    tmp = out / "tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    reps = 1 if a.quick else 3
    cpu = next((l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text().splitlines()
                if l.startswith("model name")), "unknown CPU")
    machine = f"{cpu}, {os.cpu_count()} CPUs"
    load = [loadavg()]
    results = {"seed": setting(exe, tmp, "seed", ["--parity", "--refine", 0], reps),
               "default": setting(exe, tmp, "default", ["--parity"], reps),
               "no_parity": setting(exe, tmp, "noparity", ["--refine", 0], 1)}
    load.append(loadavg())
    write(out, results, machine, load)


if __name__ == "__main__":
    main()
