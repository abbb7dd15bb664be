#!/usr/bin/python3
"""Lossy LBG partitioning (seed 002 §3.6.5) on the seed's Table 3.3 job
(brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3, parity, the scan
alone: --refine 0, as bench/table33.py runs the seed's algorithm), side by
side with the exact search in alternating runs:

  exact              no --lbg
  lbg P              --lbg P on level 0 (the seed's choice), P in 64, 200, 256
  lbg-exact P        --lbg P --lbg-exact: exact pruning, the exact bytes

Per configuration: median seconds of level 0 and of the whole job, the
codebook builds (level 0's sets that are partitioned: the scan's causal
L; the full window only when queried often enough), level 0 without
them, the speed-ups over exact, the share
of reference vectors compared per query and the seed's ideal
f_B = |V| / (P + |V| / P) for the class size |V|; against the exact run's
copy map (--copy-map-raw): the fraction of W_B x W_B blocks and of pixels
whose source differs, and the exact best-match error of the image
(`texsyn quality`). Writes bench/results/lbg.md and lbg.json with the CPU
and the load average around the runs (figures measured on a busy machine
say so).
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
SIZE, WB = 1024, 3
JOB = ["--size", f"{SIZE}x{SIZE}", "--levels", 5, "--wn", 7, "--wb", WB, "--parity", "--refine", 0,
       "--threads", 2, "--quiet"]
SEED = {"lbg_level0": 4.86, "mmx_level0": 569.13, "total_opt": 20.30}  # Table 3.3, seconds


def run(exe, args):
    p = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"bench: texsyn {' '.join(map(str, args))} failed:\n{p.stderr}")
    return p


def configs(quick):
    cs = [("exact", [])]
    for p in ([64, 256] if quick else [64, 200, 256]):
        cs.append((f"lbg {p}", ["--lbg", p]))
    cs.append(("lbg-exact 256", ["--lbg", 256, "--lbg-exact"]))
    return cs


def one_run(exe, tmp, name, extra):
    tag = name.replace(" ", "-")
    rep, raw, img = tmp / f"{tag}.json", tmp / f"{tag}.raw", tmp / f"{tag}.png"
    run(exe, ["synth", "--embedded", "--ref", DATA / "textures" / "brick.png", "-o", img, *JOB,
              "--report", rep, "--copy-map-raw", raw, *extra])
    r = json.loads(rep.read_text())
    l0 = next(l for l in r["levels"] if l["level"] == 0)
    build = sum(c.get("seconds", 0.0) for c in l0["lbg"]["sets"]) if "lbg" in l0 else 0.0
    return {"total": r["seconds"], "level0": l0["seconds"], "build": build, "report": r}, raw, img


def changed(raw_a, raw_b):
    """Fractions of blocks and pixels whose copy-map source differs."""
    a, b = memoryview(raw_a.read_bytes()).cast("Q"), memoryview(raw_b.read_bytes()).cast("Q")
    n = SIZE * SIZE  # one u64 (x, y) per pixel
    diff = [x != y for x, y in zip(a, b)]
    nb = (SIZE + WB - 1) // WB
    blocks = 0
    for by in range(nb):
        for bx in range(nb):
            if any(diff[y * SIZE + x] for y in range(by * WB, min(SIZE, by * WB + WB))
                   for x in range(bx * WB, min(SIZE, bx * WB + WB))):
                blocks += 1
    return blocks / (nb * nb), sum(diff) / n


def cpu_busy():
    """Seconds the machine's CPUs were busy, and the CPU seconds of this
    script's finished children (the runs): their difference over a stretch
    of wall time is what others used meanwhile."""
    f = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    busy = (sum(f[:8]) - f[3] - f[4]) / os.sysconf("SC_CLK_TCK")  # all but idle and iowait
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return busy, ru.ru_utime + ru.ru_stime


def cpu():
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip() + f", {os.cpu_count()} cores"
    return "unknown"


def measure(exe, tmp, reps, quick):
    cs = configs(quick)
    runs = {name: [] for name, _ in cs}
    files = {}
    t0, (b0, own0) = time.time(), cpu_busy()
    for i in range(reps):  # alternating: every configuration once per round
        order = cs if i % 2 == 0 else list(reversed(cs))
        for name, extra in order:
            r, raw, img = one_run(exe, tmp, name, extra)
            runs[name].append(r)
            files[name] = (raw, img)
    b1, own1 = cpu_busy()
    others = max(0.0, ((b1 - b0) - (own1 - own0)) / (time.time() - t0))  # cores others kept busy
    return cs, runs, files, others


def summarise(exe, cs, runs, files):
    exact_raw = files["exact"][0]
    ex0 = statistics.median(r["level0"] for r in runs["exact"])
    ext = statistics.median(r["total"] for r in runs["exact"])
    rows = []
    for name, extra in cs:
        rs = runs[name]
        med = lambda k: statistics.median(r[k] for r in rs)
        rep = rs[-1]["report"]
        l0 = next(l for l in rep["levels"] if l["level"] == 0)
        lbg = l0.get("lbg")
        row = {"config": name, "args": [str(a) for a in extra], "runs": len(rs), "total_s": med("total"),
               "level0_s": med("level0"), "build_s": med("build"), "level0_search_s": med("level0") - med("build"),
               "comparisons_level0": l0["comparisons"]}
        row["speedup_level0"] = ex0 / row["level0_s"]
        row["speedup_level0_search"] = ex0 / row["level0_search_s"]
        row["speedup_total"] = ext / row["total_s"]
        if lbg:
            p = int(extra[1])
            vc = l0["vectors"] / 4  # a parity class
            row["scanned_fraction"] = lbg["scanned_fraction"]
            row["seed_fb"] = vc / (p + vc / p)
            row["measured_fb"] = 1 / (lbg["scanned_fraction"] + p / vc)
            row["sets"] = lbg["sets"]
        blocks, pixels = changed(exact_raw, files[name][0])
        row["changed_blocks"], row["changed_pixels"] = blocks, pixels
        q = json.loads(run(exe, ["quality", "--ref", DATA / "textures" / "brick.png", "--image", files[name][1],
                                 "--samples", 3000]).stdout)
        row["quality_inner"], row["quality_seam"] = q["inner_mean"], q["seam_mean"]
        rows.append(row)
    return rows


def markdown(rows, machine, others, busy):
    lines = ["# Lossy LBG partitioning on the Table 3.3 job", "",
             "brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3, parity, the scan alone (--refine 0), "
             "2 threads, embedded; --lbg on level 0 (the seed's choice). Medians of alternating runs.",
             f"CPU: {machine}. Other processes kept {others:.2f} cores busy on average during the runs"
             + (" - **the machine was busy (other builds and tests): the times are not final**." if busy else "."),
             "",
             "| config | level 0 (s) | codebooks (s) | level 0 search (s) | whole job (s) | level 0 speed-up "
             "(search only) | job speed-up | vectors compared | seed f_B | measured f_B | blocks changed | "
             "pixels changed | error inner / seam |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        frac = f"{100 * r['scanned_fraction']:.2f} %" if "scanned_fraction" in r else "100 %"
        fb = f"{r['seed_fb']:.0f}" if "seed_fb" in r else ""
        mfb = f"{r['measured_fb']:.0f}" if "measured_fb" in r else ""
        lines.append(f"| {r['config']} | {r['level0_s']:.3f} | {r['build_s']:.3f} | {r['level0_search_s']:.3f} | "
                     f"{r['total_s']:.3f} | {r['speedup_level0']:.2f}x ({r['speedup_level0_search']:.2f}x) | "
                     f"{r['speedup_total']:.2f}x | {frac} | {fb} | {mfb} | {100 * r['changed_blocks']:.1f} % | "
                     f"{100 * r['changed_pixels']:.1f} % | {r['quality_inner']:.2f} / {r['quality_seam']:.2f} |")
    lines += ["", "Level 0's sets (the scan's causal L, the full window): its queries, and partitioned (partitions "
              "kept over the 4 parity classes, iterations, the most of any class, partition sizes min / median / "
              "max, of the last run) or exhaustive (queried too seldom for a codebook to pay):", ""]
    for r in rows:
        for c in r.get("sets", []):
            if not c["partitioned"]:
                lines.append(f"* {r['config']}, {c['window']}: {c['queries']} queries, exhaustive")
                continue
            s = c["sizes"]
            lines.append(f"* {r['config']}, {c['window']}: {c['queries']} queries, {c['partitions']} partitions, "
                         f"{c['iterations']} iterations{'' if c['converged'] else ' (the limit)'}, "
                         f"{c['seconds']:.3f} s, sizes {s['min']} / {s['median']} / {s['max']}")
    lines += ["", "Measured f_B: exhaustive comparisons over those made per query, the centroids included "
              "(1 / (vectors compared share + P / |V|)). The seed: f_B max = sqrt(|V|)/2, 15-50 measured at "
              f"P=100; its level 0 took {SEED['lbg_level0']} s with LBG against {SEED['mmx_level0']} s MMX "
              "(2.53 GHz, 2004). Blocks and pixels changed: copy-map sources that differ from the exact run's; "
              "error: `texsyn quality`, exact best-match error of 7x7 windows in grey levels."]
    return "\n".join(lines) + "\n"


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
    cs, runs, files, others = measure(exe, tmp, reps, a.quick)
    rows = summarise(exe, cs, runs, files)
    busy = others > 0.2
    machine = cpu()
    (out / "lbg.md").write_text(markdown(rows, machine, others, busy))
    (out / "lbg.json").write_text(json.dumps({"cpu": machine, "other_cores_busy": others, "busy": busy,
                                              "job": [str(j) for j in JOB], "rows": rows}, indent=1))
    print((out / "lbg.md").read_text())


if __name__ == "__main__":
    main()
