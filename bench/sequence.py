#!/usr/bin/python3
"""A 10-frame stylization sequence (`texsyn stylize --frames`) against the
same 10 frames run as 10 separate jobs, side by side in one run.

The scene: the StyLit scene at half size (600x456), its 4 target render
passes panned: frame f is the 1152x876 cut at (4f, 3f) of each target pass,
scaled to 600x456 (a camera moving right and down); the exemplar and the
source passes are the same for every frame. Search: patchmatch (auto's
choice depends on the pool's speed, so two set-ups would not run the same
job). Four ways, alternating in every run:

  cluster sequence   one `--frames 1..10 --server` command: 10 jobs submitted
                     at once, run by the coordinator 2 at a time (--jobs 2);
  cluster separate   10 `texsyn stylize --server` commands, one after the
                     other;
  embedded sequence  one `--frames 1..10 --threads 2` command;
  embedded separate  10 `texsyn stylize --threads 2` commands.

The cluster is a coordinator and 2 workers of 1 thread on loopback, started
afresh for each cluster way, so each starts with no exemplar on the workers;
the workers' Modbus registers then say how many PatchMatch sources each
loaded. Every way must give the same bytes for every frame.

Writes bench/results/sequence.{md,json}.
Usage: bench/sequence.py --build BUILD [--runs 2] [--quick]
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cluster import start, stop, wait_ready  # noqa: E402
from stylize import cpu, loadavg  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
PASSES = ("fullgi", "dirdif", "dirspc", "indirb")
WAYS = ("cluster sequence", "cluster separate", "embedded sequence", "embedded separate")


def oiiotool(*args):
    subprocess.run(["oiiotool", *map(str, args)], check=True, capture_output=True)


def make_scene(d, frames, size):
    w, h = size
    oiiotool(DATA / "stylit/source_style.png", "--resize", f"{w}x{h}", "-o", d / "style.png")
    for p in PASSES:
        oiiotool(DATA / f"stylit/source_{p}.png", "--resize", f"{w}x{h}", "-o", d / f"src_{p}.png")
        for f in frames:
            oiiotool(DATA / f"stylit/target_{p}.png", "--cut", f"1152x876+{4 * f}+{3 * f}", "--resize", f"{w}x{h}",
                     "-o", d / f"tgt_{p}_{f:04d}.png")


def scene_args(d, target):
    args = ["stylize", "--style", d / "style.png", "--search", "patchmatch", "--quiet"]
    for p in PASSES:
        args += ["--guide", d / f"src_{p}.png", d / target(p), "--weight", "0.5"]
    return args


class Pool:
    """A coordinator and 2 one-thread workers with Modbus planes."""

    def __init__(self, build, tmp, tag):
        self.procs, self.modbus = [], []
        addrs = []
        for i in range(2):
            p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1, "--modbus", 0],
                         tmp / f"{tag}-w{i}.log")
            self.procs.append(p)
            addrs.append(a)
            self.modbus.append(re.search(r"\(modbus (\S+)\)", p.banner).group(1))
        p, self.addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / f"spool-{tag}",
                              "--jobs", 2, "--workers", ",".join(addrs)], tmp / f"{tag}-server.log")
        self.procs.append(p)
        wait_ready(build, self.addr, 2)

    def sources_loaded(self, build):
        """Each worker's PatchMatch sources loaded, from its registers."""
        out = []
        for addr in self.modbus:
            regs = subprocess.run([build / "texsyn", "modbus", addr], capture_output=True, text=True,
                                  check=True).stdout
            out.append(int(dict(line.split(" ", 1) for line in regs.splitlines())["sources_loaded"]))
        return out

    def down(self):
        stop(self.procs)


def run_way(build, tmp, d, frames, way, run_no):
    outdir = tmp / f"{way.replace(' ', '-')}-{run_no}"
    outdir.mkdir()
    pool = Pool(build, tmp, f"{way.replace(' ', '-')}-{run_no}") if way.startswith("cluster") else None
    where = ["--server", pool.addr] if pool else ["--threads", 2]
    t0 = time.monotonic()
    if way.endswith("sequence"):
        cmd = [*scene_args(d, lambda p: f"tgt_{p}_%04d.png"), "--frames", f"{frames[0]}..{frames[-1]}",
               "-o", outdir / "out_%04d.png", *where]
        subprocess.run([str(build / "texsyn"), *map(str, cmd)], check=True, capture_output=True)
    else:
        for f in frames:
            cmd = [*scene_args(d, lambda p, f=f: f"tgt_{p}_{f:04d}.png"), "-o", outdir / f"out_{f:04d}.png", *where]
            subprocess.run([str(build / "texsyn"), *map(str, cmd)], check=True, capture_output=True)
    wall = time.monotonic() - t0
    loaded = pool.sources_loaded(build) if pool else None
    if pool:
        pool.down()
    outputs = {f: (outdir / f"out_{f:04d}.png").read_bytes() for f in frames}
    return wall, loaded, outputs


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="4 frames at 300x228, 1 run")
    a = ap.parse_args()
    build, out = Path(a.build).resolve(), Path(a.out)
    frames = list(range(1, 5 if a.quick else 11))
    size = (300, 228) if a.quick else (600, 456)
    runs = 1 if a.quick else a.runs
    rows, reference = [], None
    with tempfile.TemporaryDirectory(prefix="texsyn-seq-") as t:
        tmp = Path(t)
        make_scene(tmp, frames, size)
        for r in range(runs):
            order = WAYS if r % 2 == 0 else tuple(reversed(WAYS))
            for way in order:
                la = loadavg()
                wall, loaded, outputs = run_way(build, tmp, tmp, frames, way, r)
                if reference is None:
                    reference = outputs
                same = outputs == reference
                rows.append({"run": r + 1, "way": way, "seconds": wall, "per_frame": wall / len(frames),
                             "sources_loaded_per_worker": loaded, "same_bytes": same, "loadavg_before": la})
                print(f"run {r + 1} {way}: {wall:.1f} s ({wall / len(frames):.2f} s a frame), "
                      f"sources loaded {loaded}, same bytes {same}", flush=True)
                if not same:
                    sys.exit(f"bench: {way} gave other bytes than {rows[0]['way']}")
    med = {w: statistics.median(x["seconds"] for x in rows if x["way"] == w) for w in WAYS}
    ratios = {}
    for kind in ("cluster", "embedded"):
        per_run = [next(x["seconds"] for x in rows if x["run"] == r + 1 and x["way"] == f"{kind} sequence") /
                   next(x["seconds"] for x in rows if x["run"] == r + 1 and x["way"] == f"{kind} separate")
                   for r in range(runs)]
        ratios[kind] = statistics.median(per_run)
    result = {"cpu": cpu(), "date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()),
              "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                       cwd=REPO).stdout.strip(),
              "frames": len(frames), "size": f"{size[0]}x{size[1]}", "runs": runs, "rows": rows,
              "median_seconds": med, "median_ratio_sequence_over_separate": ratios}
    out.mkdir(parents=True, exist_ok=True)
    (out / "sequence.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"# A {len(frames)}-frame stylization sequence against {len(frames)} separate jobs", "",
             f"CPU: {result['cpu']}; {result['date']}, commit {result['commit']}; {runs} run(s), the four ways "
             "alternating (order reversed every other run). Scene: the StyLit scene at "
             f"{result['size']}, 4 render-pass guides at weight 0.5, the target passes panned 4 px right and 3 px "
             "down a frame (bench/sequence.py); `--search patchmatch`. Cluster: a coordinator (`--jobs 2`) and 2 "
             "workers of 1 thread on loopback, started afresh for each way; embedded: `--threads 2`.", "",
             "| way | median wall s | s a frame | sequence / separate (median of per-run ratios) | PatchMatch sources "
             "each worker loaded |", "|---|---|---|---|---|"]
    for w in WAYS:
        loaded = next(x["sources_loaded_per_worker"] for x in rows if x["way"] == w)
        ratio = f"{ratios[w.split()[0]]:.3f}" if w.endswith("sequence") else ""
        lines.append(f"| {w} | {med[w]:.1f} | {med[w] / len(frames):.2f} | {ratio} | "
                     f"{', '.join(map(str, loaded)) if loaded else '-'} |")
    lines += ["", "Every way gave the same bytes for every frame. The coordinator keeps the PatchMatch sources its "
              "workers hold across jobs (keyed by their content), so separate jobs on one pool reuse the exemplar "
              "too; the sequence adds frames run side by side (the coordinator's votes of one frame overlap the "
              "workers' passes of another) and one process instead of ten."]
    (out / "sequence.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
