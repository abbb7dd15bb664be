#!/usr/bin/python3
"""Scaling over worker counts: three jobs, each on a coordinator with N
one-thread workers (texsyn-worker --threads 1 --join) for every N of
--workers (default 1,2,3,4,8,16), plus the embedded run (--threads 2) for
reference and for the bytes.

Jobs:
  table33  the seed's Table 3.3 job: brick.png 512^2 -> 1024^2, L=5, W_N=7,
           W_B=3, parity, the scan alone (--refine 0), exact;
  aerial   a class map with roads (bench/mkscene, seed 7) at --aerial-size
           (2048^2; --quick 1024^2) with a catalogue of 448^2 references
           grown from the aero1.jpg crops (bench/aerial_refs.sh --grow 448):
           the size of references cut from a real orthophoto. The photograph's
           own crops (32 to 104 px high) give so little scan per query that
           the coordinator's per-block work dominates (--aerial-grow 0 runs
           them: see README, Benchmarks);
  stylit   the StyLit scene, 1200x912 (--quick: resized to 600x456), 4
           render-pass guides at weight 0.5, --search patchmatch (the same
           bytes on any pool).

Per job all configurations are up at once (one coordinator each, its
workers joined and calibrated) and the runs are interleaved: every
repetition runs every configuration once, so drift in the machine's speed
spreads over all of them. Speed-up = median T(1 worker) / median T(N),
efficiency = speed-up / N; the spread is min-max of the runs. Every output
is compared byte for byte with the embedded run's (invariant 1). Per run
the CPU seconds (utime+stime from /proc/PID/stat) of the coordinator and of
the workers are recorded, and the job report's per-level seconds.

On a machine with C cores, N > C workers oversubscribe it: beyond C the
speed-up cannot grow, and efficiency falls as C/N at best.
Writes bench/results/scaling.{md,json} and scaling.png (--name NAME: NAME.*;
scaling-aerial holds the large aerial job alone on 1 and 2 workers, the
issue's 2-core efficiency figure).
Usage: bench/scaling.py --build BUILD [--out DIR] [--quick] [--reps R]
       [--workers 1,2,4] [--jobs table33,aerial,stylit] [--aerial-size N]
       [--stylit-size WxH]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gnuplot  # noqa: E402
from cluster import start, stop, wait_ready  # noqa: E402
from stylize import cpu, loadavg  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
TICKS = os.sysconf("SC_CLK_TCK")
GUIDES = ("fullgi", "dirdif", "dirspc", "indirb")


def cpu_seconds(pid):
    """utime + stime of a live process, seconds (fields 14 and 15 of
    /proc/PID/stat, counted after the command name's closing parenthesis)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def table33_args():
    return ["synth", "--ref", DATA / "textures" / "brick.png", "--size", "1024x1024", "--levels", 5, "--wn", 7,
            "--wb", 3, "--parity", "--refine", 0]


def aerial_args(build, tmp, size, grow):
    d = tmp / f"aerial{size}"
    d.mkdir(exist_ok=True)
    subprocess.run([str(build / "bench" / "mkscene"), "--size", str(size), "--seed", "7", "-o", str(d / "scene")],
                   check=True, capture_output=True)
    extra = ["--grow", str(grow), "--texsyn", str(build / "texsyn")] if grow else []
    subprocess.run(["bash", str(REPO / "bench" / "aerial_refs.sh"), str(d), *extra], check=True, capture_output=True)
    return ["aerial", "--classes", d / "scene-classes.png", "--catalogue", d / "catalogue.json"]


def stylit_args(tmp, size):
    """The StyLit scene at full size (size None) or every image resized to
    size (WxH) with oiiotool."""
    s = DATA / "stylit"
    names = ["source_style.png", *(f"{side}_{g}.png" for g in GUIDES for side in ("source", "target"))]
    if size:
        for n in names:
            subprocess.run(["oiiotool", str(s / n), "--resize", size, "-o", str(tmp / n)], check=True,
                           capture_output=True)
        s = tmp
    args = ["stylize", "--style", s / "source_style.png", "--search", "patchmatch"]
    for g in GUIDES:
        args += ["--guide", s / f"source_{g}.png", s / f"target_{g}.png", "--weight", 0.5]
    return args


class Pool:
    """A coordinator and n one-thread workers that joined it; n = 0 is the
    embedded run (no daemons)."""

    def __init__(self, build, tmp, n):
        self.build, self.n, self.procs, self.server, self.addr = build, n, [], None, None
        if n == 0:
            return
        self.server, self.addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool",
                                        tmp / f"spool-{n}"], tmp / f"server-{n}.log")
        for i in range(n):
            self.procs.append(subprocess.Popen(
                [str(build / "texsyn-worker"), "--join", self.addr, "--threads", "1", "--name", f"w{n}-{i}"],
                stdout=subprocess.DEVNULL, stderr=open(tmp / f"worker-{n}-{i}.log", "w")))
        wait_ready(build, self.addr, n)

    def label(self):
        return "embedded" if self.n == 0 else f"{self.n}"

    def cpu(self):
        if self.n == 0:
            return 0.0, 0.0
        return cpu_seconds(self.server.pid), sum(cpu_seconds(p.pid) for p in self.procs)

    def run(self, args, tmp, tag):
        out, rep = tmp / f"{tag}.png", tmp / f"{tag}.json"
        where = ["--threads", 2] if self.n == 0 else ["--server", self.addr]
        cmd = [self.build / "texsyn", *args, "-o", out, "--report", rep, "--quiet", *where]
        c0 = self.cpu()
        t0 = time.monotonic()
        p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
        wall = time.monotonic() - t0
        if p.returncode != 0:
            sys.exit(f"bench: {' '.join(map(str, cmd))} failed:\n{p.stderr}")
        c1 = self.cpu()
        report = json.loads(rep.read_text())
        levels = {str(lv["level"]): lv["seconds"] for lv in report.get("levels", [])}
        data = out.read_bytes()
        out.unlink()
        return {"wall": wall, "coordinator_cpu": c1[0] - c0[0], "workers_cpu": c1[1] - c0[1], "levels": levels,
                "bytes": data}

    def down(self):
        if self.n:
            stop([*self.procs, self.server])


def spread(values):
    return [min(values), max(values)]


def measure(build, tmp, name, args, counts, reps):
    pools = []
    try:
        for n in [0, *counts]:
            pools.append(Pool(build, tmp, n))
        runs = {p.label(): [] for p in pools}
        want = None
        for r in range(reps):  # round robin: every configuration once per repetition
            for p in pools:
                res = p.run(args, tmp, f"{name}-{p.label()}-{r}")
                if p.n == 0 and want is None:
                    want = res["bytes"]
                res["identical"] = res.pop("bytes") == want
                runs[p.label()].append(res)
                print(f"{name} {p.label():>8}: {res['wall']:.2f} s, identical {res['identical']}", flush=True)
    finally:
        for p in pools:
            p.down()
    return summarize(runs, counts)


def summarize(runs, counts):
    rows = []
    base = statistics.median(r["wall"] for r in runs["1"])
    for label, rs in runs.items():
        walls = [r["wall"] for r in rs]
        med = statistics.median(walls)
        n = 0 if label == "embedded" else int(label)
        row = {"workers": n, "label": label, "median_s": med, "spread_s": spread(walls), "runs_s": walls,
               "identical": all(r["identical"] for r in rs),
               "coordinator_cpu_s": statistics.median(r["coordinator_cpu"] for r in rs),
               "workers_cpu_s": statistics.median(r["workers_cpu"] for r in rs),
               "levels_s": {lv: statistics.median(r["levels"][lv] for r in rs) for lv in rs[0]["levels"]}}
        if n:
            row["speedup"] = base / med
            row["speedup_spread"] = [base / max(walls), base / min(walls)]
            row["efficiency"] = row["speedup"] / n
            row["efficiency_spread"] = [v / n for v in row["speedup_spread"]]
        rows.append(row)
    return rows


def markdown(res):
    lines = ["# Scaling over worker counts", "",
             f"CPU: {res['cpu']}; **{res['cores']} cores** (nproc). Workers: `texsyn-worker --threads 1 --join`, "
             "each configuration its own coordinator, all on this machine: "
             f"N > {res['cores']} workers oversubscribe the {res['cores']} cores, so beyond {res['cores']} the "
             f"speed-up cannot grow and efficiency falls as {res['cores']}/N at best.",
             f"Median of {res['reps']} runs per configuration, interleaved (round robin); spread min-max; speed-up = "
             "T(1 worker) / T(N), efficiency = speed-up / N, both from medians. Embedded: `--threads 2`, no daemons. "
             "CPU s: utime+stime of the coordinator and of all workers during the run (/proc/PID/stat). "
             f"Load average at the start: {res['loadavg']:.2f}{' (machine busy)' if res['busy'] else ''}.", ""]
    for job in res["jobs"]:
        lines += [f"## {job['name']}: {job['title']}", "", f"`texsyn {job['command']}`", "",
                  "| workers | median s | spread s | speed-up | spread | efficiency | spread | coordinator CPU s | "
                  "workers CPU s | per level s (coarsest first) | identical to embedded |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in job["rows"]:
            lv = " / ".join(f"{r['levels_s'][k]:.2f}" for k in sorted(r["levels_s"], key=int, reverse=True))
            sp = (f"{r['speedup']:.2f} | {r['speedup_spread'][0]:.2f}-{r['speedup_spread'][1]:.2f} | "
                  f"{r['efficiency']:.2f} | {r['efficiency_spread'][0]:.2f}-{r['efficiency_spread'][1]:.2f}"
                  if r["workers"] else "- | - | - | -")
            lines.append(f"| {r['label']} | {r['median_s']:.2f} | {r['spread_s'][0]:.2f}-{r['spread_s'][1]:.2f} | "
                         f"{sp} | {r['coordinator_cpu_s']:.2f} | {r['workers_cpu_s']:.2f} | {lv} | "
                         f"{r['identical']} |")
        lines.append("")
    return "\n".join(lines) + "\n"


def plot(res, out, name="scaling"):
    series, top = [], max(res["counts"])
    series.append(gnuplot.Series("ideal (speed-up = N)", [(n, n) for n in res["counts"]], "lines", "dt 3 lc rgb 'gray'"))
    cores = res["cores"]
    series.append(gnuplot.Series(f"bound of {cores} cores", [(n, min(n, cores)) for n in res["counts"]], "lines",
                                 "dt 2 lc rgb 'black'"))
    for job in res["jobs"]:
        pts = [(r["workers"], r["speedup"], *r["speedup_spread"]) for r in job["rows"] if r["workers"]]
        series.append(gnuplot.Series(job["name"], pts))
    return gnuplot.lines(out / f"{name}.png", series, f"Speed-up over 1 worker ({cores} cores; bars: min-max)",
                         "workers (texsyn-worker --threads 1)", "speed-up T(1)/T(N)", logx=True, logy=True,
                         marks=[("x", cores, f"{cores} cores")], xtics=res["counts"],
                         extra=[f"set xrange [0.9:{top * 1.1}]", f"set yrange [0.25:{top * 1.1}]",
                                "set key bottom left"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--quick", action="store_true", help="workers 1,2,4,16, 2 runs, aerial 1024^2, StyLit 600x456")
    ap.add_argument("--reps", type=int)
    ap.add_argument("--workers")
    ap.add_argument("--jobs", default="table33,aerial,stylit")
    ap.add_argument("--name", default="scaling", help="results NAME.md/.json/.png (default scaling)")
    ap.add_argument("--aerial-size", type=int)
    ap.add_argument("--aerial-grow", type=int, default=448,
                    help="catalogue references grown to N x N (0: the photograph's crops)")
    ap.add_argument("--stylit-size", help="WxH: the StyLit scene resized (default: full size, --quick 600x456)")
    a = ap.parse_args()
    build, out = Path(a.build).resolve(), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    counts = [int(v) for v in (a.workers or ("1,2,4,16" if a.quick else "1,2,3,4,8,16")).split(",")]
    if counts[0] != 1:
        sys.exit("bench: --workers must start with 1 (the speed-up's base)")
    reps = a.reps or (2 if a.quick else 3)
    size = a.aerial_size or (1024 if a.quick else 2048)
    stylit_size = a.stylit_size or ("600x456" if a.quick else None)
    res = {"cpu": cpu(), "cores": os.cpu_count(), "loadavg": loadavg(), "busy": loadavg() > 0.5, "reps": reps,
           "counts": counts, "quick": a.quick, "jobs": []}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        jobs = {"table33": ("brick 512^2 -> 1024^2, L=5, W_N=7, W_B=3, parity, scan only (the seed's Table 3.3 job)",
                            table33_args),
                "aerial": (f"aerial scene {size}^2 (mkscene seed 7, defaults), references "
                           + (f"grown to {a.aerial_grow}^2 from" if a.aerial_grow else "cut from") + " aero1.jpg",
                           lambda: aerial_args(build, tmp, size, a.aerial_grow)),
                "stylit": (f"StyLit scene {stylit_size or '1200x912'}, 4 guides at weight 0.5, --search patchmatch",
                           lambda: stylit_args(tmp, stylit_size))}
        for name in a.jobs.split(","):
            if name not in jobs:
                sys.exit(f"bench: unknown job {name!r}; the jobs are {', '.join(jobs)}")
            title, make = jobs[name]
            args = make()
            rows = measure(build, tmp, name, args, counts, reps)
            res["jobs"].append({"name": name, "title": title, "rows": rows,
                                "command": " ".join(str(v) for v in args).replace(str(tmp), "TMP")})
    res["date"] = time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime())
    (out / f"{a.name}.json").write_text(json.dumps(res, indent=1) + "\n")
    md = markdown(res)
    (out / f"{a.name}.md").write_text(md)
    plot(res, out, a.name)
    print(md)
    if not all(r["identical"] for job in res["jobs"] for r in job["rows"]):
        sys.exit("bench: a cluster output differs from the embedded one")


if __name__ == "__main__":
    main()
