#!/usr/bin/python3
"""The seed's Table 3.3 (Stahlhut 2004: brick.png 512x512 -> 1024x1024,
L=5, W_N=7, W_B=3) column by column, each column next to the seed's own:

  basis      scalar kernel, no parity          (TEXSYN_SIMD=scalar)
  +parity    scalar kernel, parity             (--parity)
  +SIMD      the best SIMD variant, parity     (the seed: +MMX)
  +copy map  + the copy-map shortcut           (--copy-accel, lossy, levels 1/0)
  +cluster   + 4 one-thread workers on loopback (texsyn-worker --join), which
             share this machine's cores with the coordinator (the seed: 4 CPUs)
  +LBG       + --lbg 64 at levels 1 and 0, embedded (the seed's policy for
             l = 0, 1: "LBG + copy maps"; the seed gives only level 0)
  opt.       the per-level minimum over the columns, as the seed's

Every column runs the seed's algorithm: the scan alone (--refine 0), 2 scan
threads. Columns are measured side by side in one run, interleaved (every
repetition runs every column once); medians, spread min-max. Factors are
the basis total over the column's, as the seed's factor row.

The scalar columns are measured on the coarse levels 4..2 only (a full
scalar run takes many minutes); levels 1 and 0 are extrapolated from their
comparisons (with parity: counted in the +SIMD run; without: blocks x
vectors, the exhaustive scan) at the scalar rate measured on level 2 of the
same column: marked * in the table.
Also the quality figures and example pictures of the job.
Writes bench/results/table33.{md,json}, table33.png, table33-totals.png.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gnuplot  # noqa: E402
from scaling import Pool  # noqa: E402
from stylize import cpu, loadavg  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
LEVELS = range(4, -1, -1)
# Stahlhut 2004, Table 3.3 (verbatim, ../shared/digests/002 §3.6.7), seconds
# per level; None: the seed gives no figure. Totals and factors as printed.
SEED_COLUMNS = ["basis", "+parity", "+SIMD", "+copy map", "+cluster", "+LBG", "opt."]
SEED_TABLE = {
    "basis": {4: 0.05, 3: 2.01, 2: 37.51, 1: 642.26, 0: 10914.00},
    "+parity": {4: 0.05, 3: 0.51, 2: 9.40, 1: 161.44, 0: 2740.46},
    "+SIMD": {4: 0.02, 3: 0.12, 2: 2.04, 1: 35.03, 0: 569.13},
    "+copy map": {4: 0.02, 3: 0.12, 2: 2.04, 1: 22.94, 0: 259.26},
    "+cluster": {4: 0.02, 3: 0.74, 2: 3.45, 1: 13.26, 0: 89.94},
    "+LBG": {4: None, 3: None, 2: None, 1: None, 0: 4.86},
    "opt.": {4: 0.02, 3: 0.12, 2: 2.04, 1: 13.26, 0: 4.86},
}
SEED_TOTAL = {"basis": 11595.83, "+parity": 2911.86, "+SIMD": 606.34, "+copy map": 284.38, "+cluster": 107.41,
              "+LBG": None, "opt.": 20.30}
SEED_FACTOR = {"basis": 1, "+parity": 4, "+SIMD": 19, "+copy map": 41, "+cluster": 108, "+LBG": None, "opt.": 571}
JOB = ["--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3, "--refine", 0, "--quiet"]
CLUSTER_WORKERS = 4
LBG = ["--lbg", 64, "--lbg-levels", "1,0"]


def run(exe, args, env=None):
    e = dict(os.environ)
    e.update(env or {})
    p = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, env=e)
    if p.returncode != 0:
        sys.exit(f"bench: texsyn {' '.join(map(str, args))} failed:\n{p.stderr}")
    return p


class Column:
    """One column of the table: extra options, an environment, and where it
    runs (None: embedded with 2 threads; a Pool: on that cluster)."""

    def __init__(self, name, extra, env=None, stop_level=None):
        self.name, self.extra, self.env, self.stop_level = name, extra, env or {}, stop_level
        self.pool, self.reports = None, []

    def run(self, exe, tmp, i):
        rep = tmp / f"{self.name}-{i}.json".replace("+", "plus-").replace(" ", "-")
        where = ["--server", self.pool.addr] if self.pool else ["--threads", 2]
        stop = ["--stop-level", self.stop_level] if self.stop_level is not None else []
        run(exe, ["synth", "--ref", DATA / "textures" / "brick.png", "-o", tmp / f"t33-{i}.png", *JOB,
                  "--report", rep, *self.extra, *stop, *where], self.env)
        self.reports.append(json.loads(rep.read_text()))

    def levels(self):
        """Per level: median seconds, min-max and the counted comparisons."""
        out = {}
        for lv in self.reports[0]["levels"]:
            times = [next(x for x in r["levels"] if x["level"] == lv["level"])["seconds"] for r in self.reports]
            out[lv["level"]] = {"seconds": statistics.median(times), "spread": [min(times), max(times)],
                                "comparisons": lv["comparisons"], "blocks": lv["blocks"], "vectors": lv["vectors"],
                                "measured": True}
        return out


def extrapolate(scalar, comparisons):
    """Scalar levels below the measured ones at the scalar rate of level 2,
    from the comparisons those levels take (comparisons: level -> count)."""
    rate = scalar[2]["comparisons"] / scalar[2]["seconds"]
    for l in LEVELS:
        if l not in scalar:
            t = comparisons[l] / rate
            scalar[l] = {"seconds": t, "spread": [t, t], "comparisons": comparisons[l], "measured": False}
    return rate


def exhaustive(basis, simd):
    """The comparisons of the basis (no parity, every block against every
    vector) at every level: blocks x vectors, from the SIMD run's geometry.
    Checked on the levels the basis measured, so a change in how the search
    counts cannot pass silently."""
    for l, v in basis.items():
        if v["comparisons"] != v["blocks"] * v["vectors"]:
            sys.exit(f"bench: level {l} of the basis counted {v['comparisons']} comparisons, not blocks x vectors "
                     f"({v['blocks']} x {v['vectors']}): the extrapolation of levels 1 and 0 no longer holds")
    return {l: simd[l]["blocks"] * simd[l]["vectors"] for l in LEVELS}


def measure(exe, build, tmp, reps):
    scalar = {"TEXSYN_SIMD": "scalar"}
    cols = [Column("basis", [], scalar, stop_level=2), Column("+parity", ["--parity"], scalar, stop_level=2),
            Column("+SIMD", ["--parity"]), Column("+copy map", ["--parity", "--copy-accel"]),
            Column("+cluster", ["--parity", "--copy-accel"]), Column("+LBG", ["--parity", "--copy-accel", *LBG])]
    cols[4].pool = Pool(build, tmp, CLUSTER_WORKERS)
    try:
        for i in range(reps):  # interleaved: every repetition runs every column once
            for c in cols:
                c.run(exe, tmp, i)
                print(f"table33 {c.name}: {c.reports[-1]['seconds']:.2f} s", flush=True)
    finally:
        cols[4].pool.down()
    res = {c.name: c.levels() for c in cols}
    rates = {"basis": extrapolate(res["basis"], exhaustive(res["basis"], res["+SIMD"])),
             "+parity": extrapolate(res["+parity"], {l: v["comparisons"] for l, v in res["+SIMD"].items()})}
    res["opt."] = {l: min((res[c][l] for c in res), key=lambda v: v["seconds"]) for l in LEVELS}
    lossy = {c.name: c.reports[0]["search"].get("lossy", []) for c in cols}
    return res, rates, lossy


def quality_figures(exe, tmp, out):
    rows = []
    for tex in ("brick", "grass"):
        ref = DATA / "textures" / f"{tex}.png"
        synth = out / f"example-{tex}-512.png"
        run(exe, ["synth", "--ref", ref, "-o", synth, "--size", "512x512", "--levels", 5, "--quiet",
                  "--copy-map", out / f"example-{tex}-512-copymap.png", "--report", tmp / "q.json"])
        usage_off = json.loads((tmp / "q.json").read_text())["usage"]["variance"]
        run(exe, ["synth", "--ref", ref, "-o", out / f"example-{tex}-512-usage4.png", "--size", "512x512",
                  "--levels", 5, "--usage-weight", 4, "--quiet", "--report", tmp / "q4.json"])
        usage_on = json.loads((tmp / "q4.json").read_text())["usage"]["variance"]
        shuffle = tmp / f"shuffle-{tex}.png"
        run(exe, ["shuffle", "--ref", ref, "-o", shuffle, "--size", "512x512", "--block", 16])
        q = json.loads(run(exe, ["quality", "--ref", ref, "--image", synth, "--samples", 3000]).stdout)
        qs = json.loads(run(exe, ["quality", "--ref", ref, "--image", shuffle, "--samples", 3000]).stdout)
        rows.append((tex, q, qs, usage_off, usage_on))
    return rows


def fmt(v):
    if v is None:
        return "-"
    return f"{v['seconds']:.3f}{'' if v['measured'] else '*'}"


def total(levels):
    return sum(v["seconds"] for v in levels.values())


def factors(res):
    base = total(res["basis"])
    return {c: base / total(res[c]) for c in res}


def write_markdown(out, info, res, rates, lossy, quality):
    f = factors(res)
    head = " | ".join(f"{c} | seed {c}" for c in SEED_COLUMNS)
    lines = ["# Table 3.3 column by column: brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3", "",
             f"CPU: {info['cpu']}; {info['cores']} cores (nproc). Load average at the start {info['loadavg']:.2f}"
             f"{' (machine busy: figures under load)' if info['busy'] else ''}. Best SIMD variant `{info['best']}`.",
             f"The scan alone (--refine 0), 2 scan threads, exact unless named; median of {info['reps']} interleaved "
             "runs per column (spread in table33.json). Columns cumulative as the seed's: basis = scalar, no parity; "
             f"+parity = scalar, parity; +SIMD = `{info['best']}`, parity (the seed: +MMX); +copy map = "
             "`--copy-accel` (lossy); +cluster = +copy map on "
             f"{CLUSTER_WORKERS} one-thread workers on loopback, sharing the {info['cores']} cores with the "
             "coordinator (the seed: 4 CPUs); +LBG = +copy map with `" + " ".join(map(str, LBG)) + "`, embedded "
             "(the seed gives level 0 only); opt. = per-level minimum over the columns. "
             "Seed: 2.53 GHz CPU, 2004.",
             "* = extrapolated: scalar levels 1 and 0 from their comparisons (with parity: counted in the +SIMD run; "
             "without: blocks x vectors, the exhaustive scan, checked on the measured levels) at the scalar rate "
             f"measured on level 2 ({rates['basis']:.3g} comparisons/s without parity, {rates['+parity']:.3g} with).",
             "", f"| level | {head} |", "|---" * (1 + 2 * len(SEED_COLUMNS)) + "|"]
    for l in LEVELS:
        cells = []
        for c in SEED_COLUMNS:
            seed = SEED_TABLE[c][l]
            cells += [fmt(res[c].get(l)), "-" if seed is None else f"{seed:.2f}"]
        lines.append(f"| {l} | " + " | ".join(cells) + " |")
    cells = []
    for c in SEED_COLUMNS:
        extrap = any(not v["measured"] for v in res[c].values())
        cells += [f"{total(res[c]):.3f}{'*' if extrap else ''}",
                  "-" if SEED_TOTAL[c] is None else f"{SEED_TOTAL[c]:.2f}"]
    lines.append("| total | " + " | ".join(cells) + " |")
    cells = []
    for c in SEED_COLUMNS:
        cells += [f"{f[c]:.0f}", "-" if SEED_FACTOR[c] is None else str(SEED_FACTOR[c])]
    lines.append("| factor | " + " | ".join(cells) + " |")
    lines += ["", "Lossy shortcuts each column's report names: " +
              "; ".join(f"{c}: {', '.join(v) if v else 'none (exact)'}" for c, v in lossy.items()) + ".",
              f"Parity on the measured scalar level 2: {res['basis'][2]['seconds'] / res['+parity'][2]['seconds']:.2f}x "
              "faster (a quarter of the comparisons; the seed: 4x).", "",
              "# Quality (exact best-match error of 7x7 windows, grey levels per pixel)", "",
              "| texture | synthesis inner | synthesis seam | 16x16 block shuffle inner | usage variance off | "
              "usage variance weight 4 |", "|---|---|---|---|---|---|"]
    for tex, q, qs, uoff, uon in quality:
        lines.append(f"| {tex} | {q['inner_mean']:.2f} | {q['seam_mean']:.2f} | {qs['inner_mean']:.2f} | "
                     f"{uoff:.2f} | {uon:.2f} |")
    (out / "table33.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def plot(out, res):
    """table33.png: seconds per level, ours (solid, bars min-max) and the
    seed's (dotted); table33-totals.png: the totals column by column."""
    series = []
    for k, c in enumerate(SEED_COLUMNS[:-1]):  # the same colour for a column and the seed's
        series.append(gnuplot.Series(f"texsyn {c}", [(l, v["seconds"], *v["spread"]) for l, v in res[c].items()],
                                     options=f"lc {k + 1} pt 7"))
    for k, c in enumerate(SEED_COLUMNS[:-1]):
        pts = [(l, v) for l, v in SEED_TABLE[c].items() if v is not None]
        series.append(gnuplot.Series(f"2004 {c}", pts, "linespoints" if len(pts) > 1 else "points",
                                     f"dt 3 lc {k + 1} pt 6"))
    gnuplot.lines(out / "table33.png", series, "Table 3.3 job per level: texsyn (solid) and the seed, 2004 (dotted)",
                  "pyramid level", "seconds", logy=True, xtics=list(LEVELS), size=(900, 600),
                  extra=["set xrange [4.3:-0.3]", "set key outside right top"])
    cols = SEED_COLUMNS
    gnuplot.bars(out / "table33-totals.png", cols,
                 {"texsyn": [total(res[c]) for c in cols],
                  "2004 (seed)": [SEED_TOTAL[c] if SEED_TOTAL[c] is not None else SEED_TABLE[c][0] for c in cols]},
                 "Table 3.3 job, total seconds per column (seed's +LBG: level 0 only)", "seconds", logy=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--quick", action="store_true", help="2 runs per column")
    ap.add_argument("--reps", type=int)
    a = ap.parse_args()
    build, out = Path(a.build).resolve(), Path(a.out)
    exe = build / "texsyn"
    out.mkdir(parents=True, exist_ok=True)
    reps = a.reps or (2 if a.quick else 5)
    info = {"cpu": cpu(), "cores": os.cpu_count(), "loadavg": loadavg(), "busy": loadavg() > 0.5, "reps": reps,
            "best": run(exe, ["simd"]).stdout.split("(selected)")[0].split()[-1]}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        res, rates, lossy = measure(exe, build, tmp, reps)
        quality = quality_figures(exe, tmp, out)
    write_markdown(out, info, res, rates, lossy, quality)
    (out / "table33.json").write_text(json.dumps({
        **info, "columns": {c: {str(l): v for l, v in res[c].items()} for c in SEED_COLUMNS},
        "totals": {c: total(res[c]) for c in SEED_COLUMNS}, "factors": factors(res), "scalar_rates": rates,
        "lossy": lossy,
        "seed": {c: {str(l): v for l, v in SEED_TABLE[c].items()} for c in SEED_COLUMNS},
        "seed_totals": SEED_TOTAL, "seed_factors": SEED_FACTOR}, indent=1) + "\n")
    plot(out, res)


if __name__ == "__main__":
    main()
