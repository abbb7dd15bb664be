#!/usr/bin/python3
"""Cluster overhead: the seed's Table 3.3 job (brick.png 512x512 ->
1024x1024, L=5, W_N=7, W_B=3) embedded and on loopback clusters, measured
side by side in one run (runs interleaved, medians).

Configurations use the same scan thread count (2) as the embedded run:
  embedded          texsyn synth --threads 2
  1 worker x 2      a coordinator and one texsyn-worker --threads 2
  2 workers x 1     a coordinator and two texsyn-worker --threads 1
  0 workers         a lone coordinator scanning in-process (--threads 2)
The coordinator's engine and the workers share the machine's 2 cores, as
the embedded engine shares them with its scan threads.

Reported per configuration: median seconds, ratio to embedded, payload
bytes on the wire per query and round trips per level (from the job
report), and whether the output bytes equal the embedded run's.
"""
import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gnuplot  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
JOB = ["--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3, "--quiet"]


def start(args, log):
    p = subprocess.Popen([str(a) for a in args], stdout=subprocess.PIPE, stderr=open(log, "w"), text=True)
    line = p.stdout.readline()
    m = re.search(r"listening on (\S+)", line)
    if not m:
        sys.exit(f"bench: {args[0]} did not start, see {log}")
    p.banner = line  # what else it says there: a worker's Modbus address
    return p, m.group(1)


def stop(procs):
    for p in procs:
        p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=30)  # a worker holding a big slice takes a while to free it
        except subprocess.TimeoutExpired:
            p.kill()


def wait_ready(build, addr, n):
    for _ in range(1200):  # calibration of several workers on a loaded machine
        out = subprocess.run([build / "texsyn", "workers", "--server", addr], capture_output=True, text=True).stdout
        if out.count(" active ") >= n:
            return
        time.sleep(0.05)
    sys.exit(f"bench: {n} workers not ready at {addr}")


class Config:
    def __init__(self, label, workers):
        self.label, self.workers = label, workers  # workers: list of thread counts, or None = embedded
        self.name = re.sub(r"\W+", "_", label)  # for file names
        self.procs, self.addr = [], None

    def up(self, build, tmp):
        if self.workers is None:
            return
        addrs = []
        for i, t in enumerate(self.workers):
            p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", t],
                         tmp / f"{self.name}-w{i}.log")
            self.procs.append(p)
            addrs.append(a)
        args = [build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / f"spool-{self.name}",
                "--threads", 2]
        if addrs:
            args += ["--workers", ",".join(addrs)]
        p, self.addr = start(args, tmp / f"{self.name}-server.log")
        self.procs.append(p)
        wait_ready(build, self.addr, len(addrs))

    def run(self, build, tmp, extra, i):
        out, rep = tmp / f"{self.name}-{i}.png", tmp / f"{self.name}-{i}.json"
        args = [build / "texsyn", "synth", "--ref", DATA / "textures" / "brick.png", "-o", out, *JOB,
                "--report", rep, *extra]
        args += ["--threads", 2] if self.workers is None else ["--server", self.addr]
        t0 = time.monotonic()
        p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
        wall = time.monotonic() - t0
        if p.returncode != 0:
            sys.exit(f"bench: {self.name} failed:\n{p.stderr}")
        return wall, json.loads(rep.read_text()), out.read_bytes()

    def down(self):
        stop(self.procs)


def plot(results, out):
    """cluster.png: each configuration's median per mode, bars min-max."""
    modes = list(results)
    labels = [r["config"] for r in results[modes[0]]]
    gnuplot.bars(out / "cluster.png", labels, {m: [r["median_s"] for r in results[m]] for m in modes},
                 "Table 3.3 job: embedded and on loopback clusters (bars: min-max)", "wall seconds",
                 spreads={m: [(min(r["runs"]), max(r["runs"])) for r in results[m]] for m in modes},
                 size=(900, 500), extra=["set xtics font ',8'"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="2 runs, parity only")
    a = ap.parse_args()
    build, out = Path(a.build).resolve(), Path(a.out)
    reps = 2 if a.quick else a.reps
    configs = [Config("embedded", None), Config("1 worker x 2 threads", [2]),
               Config("2 workers x 1 thread", [1, 1]), Config("0 workers (lone coordinator)", [])]
    results = {}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        modes = (("parity", ["--parity"]),) if a.quick else (("parity", ["--parity"]), ("no parity", []))
        for mode, extra in modes:  # --quick: parity only (without, 3x the time, the same overhead)
            for c in configs:
                c.procs = []
                c.up(build, tmp)
            samples = {c.label: [] for c in configs}
            reports, images = {}, {}
            try:
                for i in range(reps):  # interleaved: each rep runs every config once
                    for c in configs:
                        wall, rep, img = c.run(build, tmp, extra, i)
                        samples[c.label].append(wall)
                        reports[c.label], images[c.label] = rep, img
            finally:
                for c in configs:
                    c.down()
            base = statistics.median(samples["embedded"])
            rows = []
            for c in configs:
                rep = reports[c.label]
                queries = sum(l["blocks"] for l in rep["levels"])
                wire = sum(l.get("wire_bytes", 0) for l in rep["levels"])
                med = statistics.median(samples[c.label])
                rows.append({
                    "config": c.label, "median_s": med, "runs": samples[c.label], "ratio": med / base,
                    "identical": images[c.label] == images["embedded"],
                    "wire_bytes_per_query": wire / queries if c.workers else 0,
                    "round_trips": {l["level"]: l.get("round_trips", 0) for l in rep["levels"]},
                    "engine_seconds": rep["seconds"],
                })
            results[mode] = rows
    (out / "cluster.json").write_text(json.dumps(results, indent=1))
    lines = ["Cluster overhead: Table 3.3 job (brick 512^2 -> 1024^2, L=5, W_N=7, W_B=3, default refine),",
             f"wall time of `texsyn synth` incl. submit and fetch, median of {reps} interleaved runs, 2 cores.", ""]
    for mode, rows in results.items():
        lines.append(f"{mode}:")
        lines.append(f"  {'configuration':32s} {'median s':>9s} {'x embedded':>10s} {'bytes/query':>11s} "
                     f"{'round trips L4..L0':>26s}  identical")
        for r in rows:
            rt = " ".join(str(r["round_trips"][l]) for l in sorted(r["round_trips"], reverse=True))
            lines.append(f"  {r['config']:32s} {r['median_s']:9.3f} {r['ratio']:10.3f} "
                         f"{r['wire_bytes_per_query']:11.1f} {rt:>26s}  {r['identical']}")
        lines.append("")
    (out / "cluster.txt").write_text("\n".join(lines) + "\n")
    plot(results, out)
    print("\n".join(lines))
    if not all(r["identical"] for rows in results.values() for r in rows):
        sys.exit("bench: a cluster output differs from the embedded one")


if __name__ == "__main__":
    main()
