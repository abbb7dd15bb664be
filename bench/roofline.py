#!/usr/bin/python3
"""The roofline picture of the L1 scan kernels, from bench_kernels' CSV
(kernels.csv): throughput per SIMD variant against the measured memory
read bandwidth.

Arithmetic intensity (x): operations per byte of reference data read. The
L1 scan does 3 operations per compared byte (subtract, absolute value,
add); a single-query scan compares each reference byte it reads once
(3 ops/byte), a batch of nq queries compares it nq times (3*nq ops/byte).
Performance (y): operations per second, 3 x the compared bytes per second
bench_kernels reports. The memory roof is bandwidth x intensity (the 1- and
2-thread streaming reads bench_kernels measures); the kernels ran on one
thread, so the 1-thread roof is theirs. Points: W_N=7 vectors (7 chunks),
reference set in L2 ("cache", 256 KB) and streamed from DRAM ("mem", 256 MB).

A variant is called memory-bound on a single query when its scan slows
down by more than 15% once the set streams from DRAM and it then runs at
60% or more of the 1-thread read bandwidth; otherwise compute-bound. A
batch of nq queries is memory-bound when its DRAM traffic (compared bytes
per second / nq) reaches 60% of the bandwidth.
Writes bench/results/roofline.{md,json} and roofline.png.
Usage: bench/roofline.py [--out DIR]
"""
import argparse
import csv
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gnuplot  # noqa: E402

OPS_PER_BYTE = 3  # subtract, absolute value, add per compared byte
NCHUNKS = "7"
SLOWDOWN = 0.85   # mem below this share of cache: the data's path limits it
NEAR_ROOF = 0.6   # ... and at this share of the read bandwidth or more


def load(path):
    rows = list(csv.DictReader(path.open()))
    bw = {r["kind"]: float(r["gbps"]) for r in rows if r["kind"].startswith("memread")}
    if "memread-1t" not in bw:
        sys.exit(f"bench: {path} has no memread-1t row (bench_kernels --csv writes it)")
    kern = [r for r in rows if r["nchunks"] == NCHUNKS and r["kind"] in ("single", "batch")]
    return bw, kern


def classify(bw, kern):
    out = {}
    for v in dict.fromkeys(r["variant"] for r in kern):
        get = {(r["kind"], r["where"], r["nq"]): float(r["gbps"]) for r in kern if r["variant"] == v}
        cache, mem = get[("single", "cache", "1")], get[("single", "mem", "1")]
        bound = "memory" if mem < SLOWDOWN * cache and mem >= NEAR_ROOF * bw["memread-1t"] else "compute"
        batch = max((k for k in get if k[0] == "batch" and k[1] == "mem"), key=lambda k: int(k[2]), default=None)
        bmem = get[batch] if batch else None
        bcache = get.get(("batch", "cache", batch[2])) if batch else None
        out[v] = {"single_cache_gbps": cache, "single_mem_gbps": mem, "bound": bound,
                  "share_of_bandwidth": mem / bw["memread-1t"], "batch_nq": int(batch[2]) if batch else None,
                  "batch_cache_gbps": bcache, "batch_mem_gbps": bmem,
                  # a batch's roof is the bandwidth times nq: its DRAM traffic is bmem / nq
                  "batch_bound": None if not (bmem and bcache) else
                  "memory" if bmem >= NEAR_ROOF * bw["memread-1t"] * int(batch[2]) else "compute",
                  "batch_dram_loss": None if not (bmem and bcache) else 1 - bmem / bcache}
    return out


def plot(out, bw, kern):
    ais = [OPS_PER_BYTE * n for n in (1, 32, 128)]
    lo, hi = 1, OPS_PER_BYTE * 128 * 2
    series = [gnuplot.Series(f"DRAM roof, {k[-2:]} ({g:.1f} GB/s)", [(lo, g * lo), (hi, g * hi)], "lines",
                             f"lw 2 dt {1 if k.endswith('1t') else 2} lc rgb 'black'") for k, g in sorted(bw.items())]
    for k, v in enumerate(dict.fromkeys(r["variant"] for r in kern)):
        for where, pt in (("cache", 7), ("mem", 6)):
            pts = [(OPS_PER_BYTE * int(r["nq"]), OPS_PER_BYTE * float(r["gbps"])) for r in kern
                   if r["variant"] == v and r["where"] == where]
            series.append(gnuplot.Series(f"{v}, {'set in L2' if where == 'cache' else 'set in DRAM'}", sorted(pts),
                                         "linespoints", f"lc {k + 1} pt {pt} ps 1.3 dt {1 if where == 'cache' else 3}"))
    return gnuplot.lines(out / "roofline.png", series,
                         "L1 scan kernels (W_N=7, 1 thread) against the measured memory bandwidth",
                         "arithmetic intensity: operations per byte of reference read (3 x queries per batch)",
                         "G operations / s", logx=True, logy=True, xtics=ais, size=(900, 600),
                         extra=[f"set xrange [{lo * 0.8}:{hi}]", "set key outside right top"])


def markdown(out, bw, cls):
    lines = ["# Roofline: L1 scan kernels against the memory bandwidth", "",
             f"Memory read bandwidth (streaming sum over 512 MB): {bw['memread-1t']:.1f} GB/s on 1 thread, "
             f"{bw.get('memread-2t', 0):.1f} GB/s on 2. Kernels: 1 thread, W_N=7 vectors (56 B), GB/s of "
             "reference bytes compared per second (a batch of nq queries compares each byte read nq times). "
             f"Memory-bound: the single-query scan loses more than {100 - SLOWDOWN * 100:.0f}% from L2 to DRAM and "
             f"then runs at {NEAR_ROOF * 100:.0f}% or more of the 1-thread bandwidth.", "",
             "| variant | single query, set in L2 GB/s | single query, set in DRAM GB/s | share of 1-thread bandwidth | "
             "bound (single query) | largest batch: L2 / DRAM GB/s | bound (batch) |", "|---|---|---|---|---|---|---|"]
    for v, c in cls.items():
        b = (f"{c['batch_cache_gbps']:.1f} / {c['batch_mem_gbps']:.1f} (nq {c['batch_nq']})"
             if c["batch_bound"] else "-")
        lines.append(f"| {v} | {c['single_cache_gbps']:.1f} | {c['single_mem_gbps']:.1f} | "
                     f"{c['share_of_bandwidth']:.2f} | {c['bound']} | {b} | {c['batch_bound'] or '-'} |")
    mem = [v for v, c in cls.items() if c["bound"] == "memory"]
    comp = [v for v, c in cls.items() if c["bound"] == "compute"]
    bcomp = [v for v, c in cls.items() if c["batch_bound"] == "compute"]
    bmem = [v for v, c in cls.items() if c["batch_bound"] == "memory"]
    slower = [f"{v} ({100 * c['batch_dram_loss']:.0f}%)" for v, c in cls.items()
              if c["batch_bound"] == "compute" and c["batch_dram_loss"] > 1 - SLOWDOWN]
    lines += ["", f"Compute-bound on a single query: {', '.join(comp) or 'none'} (nearly as fast from DRAM as from "
              "L2, or far below the roof: the kernel, not the data's path, limits them). Memory-bound: " +
              (', '.join(mem) or 'none') + " (near the DRAM roof: streaming a set larger than the caches, a single "
              "query cannot go faster than the memory delivers). Batching queries raises the intensity nq-fold: "
              f"batched, {', '.join(bcomp) or 'none'} are compute-bound (their DRAM traffic, GB/s / nq, is far "
              "below the bandwidth)" + (f"; {', '.join(bmem)} stay at the roof" if bmem else "") +
              (f"; slower from DRAM than from L2 all the same, not for lack of bandwidth: {', '.join(slower)}"
               if slower else "") + ".", ""]
    (out / "roofline.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="bench/results")
    a = ap.parse_args()
    out = Path(a.out)
    path = out / "kernels.csv"
    if not path.exists():
        sys.exit(f"bench: {path} missing; run build/bench/bench_kernels --csv {path} first")
    bw, kern = load(path)
    cls = classify(bw, kern)
    (out / "roofline.json").write_text(json.dumps({"bandwidth_gbps": bw, "ops_per_byte": OPS_PER_BYTE,
                                                   "variants": cls}, indent=1) + "\n")
    markdown(out, bw, cls)
    plot(out, bw, kern)


if __name__ == "__main__":
    main()
