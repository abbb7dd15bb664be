#!/usr/bin/python3
"""The seed's Table 3.3 job (brick.png 512x512 -> 1024x1024, L=5, W_N=7,
W_B=3) per level and in total, with and without parity, for the best SIMD
variant and for scalar; plus quality figures and example pictures.

The job runs the seed's algorithm: the scan alone (--refine 0); the
default refinement sweeps are timed in an extra column.

Scalar is measured on the coarse levels 4..2 only (a full scalar run takes
minutes) and levels 1 and 0 are extrapolated from the comparisons counted in
the SIMD run at the scalar rate measured on level 2: the report says so.
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
SEED_TABLE = {  # Stahlhut 2004, Table 3.3, seconds per level (+MMX column, +Cluster, opt.)
    "mmx_parity": {4: 0.02, 3: 0.12, 2: 2.04, 1: 35.03, 0: 569.13},
    "cluster4": {4: 0.02, 3: 0.74, 2: 3.45, 1: 13.26, 0: 89.94},
}


def run(exe, args, env=None):
    e = dict(os.environ)
    e.update(env or {})
    p = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, env=e)
    if p.returncode != 0:
        sys.exit(f"bench: texsyn {' '.join(map(str, args))} failed:\n{p.stderr}")
    return p


def job(exe, tmp, name, extra, env=None, reps=1):
    reports = []
    for i in range(reps):
        rep = tmp / f"{name}-{i}.json"
        run(exe, ["synth", "--ref", DATA / "textures" / "brick.png", "-o", tmp / f"{name}.png",
                  "--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3, "--quiet",
                  "--report", rep, *extra], env)
        reports.append(json.loads(rep.read_text()))
    return reports


def median_levels(reports):
    levels = {}
    for lv in reports[0]["levels"]:
        l = lv["level"]
        times = [next(x for x in r["levels"] if x["level"] == l)["seconds"] for r in reports]
        levels[l] = {"seconds": statistics.median(times), "comparisons": lv["comparisons"],
                     "vectors": lv["vectors"], "steps": lv["steps"], "blocks": lv["blocks"]}
    total = statistics.median(r["seconds"] for r in reports)
    return levels, total


def scalar_levels(exe, tmp, parity, simd_levels):
    rep = job(exe, tmp, f"scalar-{parity}", (["--parity"] if parity else []) + ["--stop-level", 2, "--threads", 2, "--refine", 0],
              env={"TEXSYN_SIMD": "scalar"})[0]
    measured = {lv["level"]: lv for lv in rep["levels"]}
    rate = measured[2]["comparisons"] / measured[2]["seconds"]
    out = {}
    for l in range(5):
        if l in measured:
            out[l] = {"seconds": measured[l]["seconds"], "measured": True}
        else:
            out[l] = {"seconds": simd_levels[l]["comparisons"] / rate, "measured": False}
    return out, rate


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


def write_markdown(out, best, sys_levels, scalar, quality, refined):
    lines = ["# Table 3.3 job: brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3", "",
             f"Best SIMD variant: `{best}`, 2 threads, embedded (local backend); exact search;",
             "the seed's algorithm (scan only, --refine 0); the last column adds texsyn's default",
             "2 refinement sweeps (parity).",
             "Medians of repeated runs; scalar levels 1 and 0 extrapolated from the counted",
             "comparisons at the scalar rate measured on level 2 (marked *).", "",
             "| level | vectors | comparisons (parity) | " + f"{best} parity (s) | {best} no parity (s) | "
             "scalar parity (s) | scalar no parity (s) | 2004 MMX+parity (s) | 2004 4-CPU cluster (s) | "
             f"{best} parity + 2 sweeps (s) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for l in range(4, -1, -1):
        sp, sn = scalar[True][0][l], scalar[False][0][l]
        fmt = lambda v: f"{v['seconds']:.3f}{'' if v['measured'] else '*'}"
        lines.append(f"| {l} | {sys_levels[True][0][l]['vectors']} | {sys_levels[True][0][l]['comparisons']:.3g} | "
                     f"{sys_levels[True][0][l]['seconds']:.3f} | {sys_levels[False][0][l]['seconds']:.3f} | "
                     f"{fmt(sp)} | {fmt(sn)} | {SEED_TABLE['mmx_parity'][l]} | {SEED_TABLE['cluster4'][l]} | "
                     f"{refined[0][l]['seconds']:.3f} |")
    tot = lambda d: sum(v["seconds"] for v in d.values())
    lines.append(f"| total | | | {sys_levels[True][1]:.3f} | {sys_levels[False][1]:.3f} | "
                 f"{tot(scalar[True][0]):.1f}* | {tot(scalar[False][0]):.1f}* | 606.34 | 107.41 | {refined[1]:.3f} |")
    lines += ["", f"Scalar rate measured on level 2: {scalar[True][1]:.3g} (parity) and "
              f"{scalar[False][1]:.3g} (no parity) comparisons/s on 2 threads.", "",
              "# Quality (exact best-match error of 7x7 windows, grey levels per pixel)", "",
              "| texture | synthesis inner | synthesis seam | 16x16 block shuffle inner | usage variance off | usage variance weight 4 |",
              "|---|---|---|---|---|---|"]
    for tex, q, qs, uoff, uon in quality:
        lines.append(f"| {tex} | {q['inner_mean']:.2f} | {q['seam_mean']:.2f} | {qs['inner_mean']:.2f} | {uoff:.2f} | {uon:.2f} |")
    (out / "table33.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def plot(out, best, sys_levels, scalar):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("bench: matplotlib missing, no plot")
        return
    levels = list(range(4, -1, -1))
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogy(levels, [sys_levels[True][0][l]["seconds"] for l in levels], "o-", label=f"{best} parity")
    ax.semilogy(levels, [sys_levels[False][0][l]["seconds"] for l in levels], "o-", label=f"{best} no parity")
    ax.semilogy(levels, [scalar[True][0][l]["seconds"] for l in levels], "s--", label="scalar parity (L1,L0 extrap.)")
    ax.semilogy(levels, [SEED_TABLE["mmx_parity"][l] for l in levels], "x:", label="2004 MMX+parity")
    ax.semilogy(levels, [SEED_TABLE["cluster4"][l] for l in levels], "x:", label="2004 4-CPU cluster")
    ax.set_xlabel("pyramid level")
    ax.set_ylabel("seconds")
    ax.invert_xaxis()
    ax.set_title("Table 3.3 job: brick 512² → 1024², L=5, W_N=7, W_B=3")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "table33.png", dpi=110)
    plot_kernels(plt, out)


def plot_kernels(plt, out):
    """Bytes per cycle of every variant, single and batched, cache and memory."""
    import csv
    path = out / "kernels.csv"
    if not path.exists():
        return
    rows = [r for r in csv.DictReader(path.open()) if r["nchunks"] == "7" and r["kind"] in ("single", "batch")
            and r["nq"] in ("1", "128")]
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.2
    for i, (kind, where) in enumerate([("single", "cache"), ("batch", "cache"), ("single", "mem"), ("batch", "mem")]):
        vals = [next((float(r["bytes_per_cycle"]) for r in rows if r["variant"] == v and r["kind"] == kind
                      and r["where"] == where), 0.0) for v in variants]
        ax.bar([k + (i - 1.5) * width for k in range(len(variants))], vals, width, label=f"{kind}, {where}")
    ax.axhline(64, color="grey", linestyle=":", label="64 B/cycle")
    ax.set_xticks(range(len(variants)))
    ax.set_xticklabels(variants)
    ax.set_ylabel("reference bytes per cycle per core")
    ax.set_title("L1 scan throughput, W_N=7 vectors (56 B), 1 core")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "kernels.png", dpi=110)


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
    best = run(exe, ["simd"]).stdout.split("(selected)")[0].split()[-1]
    reps = 1 if a.quick else 3
    sys_levels = {}
    for parity in (True, False):
        reports = job(exe, tmp, f"best-{parity}", (["--parity"] if parity else []) + ["--threads", 2, "--refine", 0],
                      reps=reps if parity else max(1, reps - 1))
        sys_levels[parity] = median_levels(reports)
    refined = median_levels(job(exe, tmp, "best-refined", ["--parity", "--threads", 2], reps=reps))
    os.replace(tmp / "best-True.png", out / "table33-brick-1024-parity.png")
    os.replace(tmp / "best-False.png", out / "table33-brick-1024.png")
    scalar = {p: scalar_levels(exe, tmp, p, sys_levels[p][0]) for p in (True, False)}
    quality = quality_figures(exe, tmp, out)
    write_markdown(out, best, sys_levels, scalar, quality, refined)
    (out / "table33.json").write_text(json.dumps({"best": best, "refined_parity": refined,
                                                  "system": {str(k): v for k, v in sys_levels.items()},
                                                  "scalar": {str(k): v for k, v in scalar.items()}}, indent=1))
    plot(out, best, sys_levels, scalar)


if __name__ == "__main__":
    main()
