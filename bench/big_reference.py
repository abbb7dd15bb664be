#!/usr/bin/python3
"""A big reference on a cluster: a 4096x4096 RGB reference (the shared aerial
photograph, aerial/aero1.jpg, resized with oiiotool; made in the work
directory, never committed) with an 11x11 window searched on colour,
embedded and on loopback clusters of 1 and 3 workers. Each run must complete
with the embedded run's bytes; the figures are every process's peak RSS,
the wall time and the slice messages the workers took in pieces.

The workers run with --max-frame 16 MiB (--frame-limit), so that each
level-0 slice (63 MB on one worker, about 21 MB each on three) is larger than
a frame and travels in pieces, as a bigger reference or its usage counters
would under the default 64 MiB. The coordinator produces every message a
chunk at a time as the worker's socket drains, so its peak RSS stays near
the embedded client's. With --baseline BUILD (the build of an older commit)
the cluster runs are repeated with that build, the default frame limit and
--batch-timeout 300 (its slice loads had a fixed deadline of --batch-timeout
+ 30 s, shorter than building a level-0 slice here).

Exact search keeps every vector: about 950 bytes per reference pixel at
level 0 for this job (both sets, causal and square), 16 GB for 4096x4096,
in the embedded process or spread over the workers. Every run starts only
if /proc/meminfo's MemAvailable covers its estimate; the figure is written
with the results. Takes about 10 minutes on 2 cores (30 with --baseline). Outside make bench.

Writes OUT/big_reference.md (and .json).
"""
import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cluster import start, stop, wait_ready  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
BYTES_PER_PIXEL = 950  # measured: 979 MB peak for a 1024x1024 reference


def job_args(ref, out, report):
    return ["synth", "--ref", ref, "-o", out, "--size", "32x32", "--levels", 2, "--wn", 11, "--wb", 3,
            "--rgb-search", "--quiet", "--report", report, "--copy-map-raw", str(out) + ".raw"]


def mem_available():
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemAvailable:"):
            return int(line.split()[1]) * 1024
    return 0


def peak_rss(pid):
    """VmHWM of a live process, in bytes."""
    m = re.search(r"VmHWM:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text())
    return int(m.group(1)) * 1024


def timed(args, log):
    """Runs a command under /usr/bin/time -v; returns (seconds, peak RSS)."""
    t0 = time.time()
    p = subprocess.run(["/usr/bin/time", "-v", *map(str, args)], stderr=open(log, "w"), stdout=subprocess.DEVNULL)
    secs = time.time() - t0
    text = Path(log).read_text()
    if p.returncode != 0:
        sys.exit(f"bench: {args[1]} failed ({p.returncode}), see {log}:\n{text[-2000:]}")
    return secs, int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", text).group(1)) * 1024


def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def need_memory(label, need, results):
    avail = mem_available()
    print(f"{label}: {avail / 2**30:.1f} GiB available, about {need / 2**30:.1f} GiB needed", flush=True)
    if avail < need * 1.1:
        sys.exit(f"bench: {label} needs about {need / 2**30:.1f} GiB, only {avail / 2**30:.1f} GiB available")
    results["mem_available"][label] = avail


def run_embedded(args, ref, work, results):
    out, report = work / "embedded.png", work / "embedded.json"
    secs, rss = timed([args.build / "texsyn", *job_args(ref, out, report), "--threads", 2], work / "embedded.time")
    results["runs"].append({"label": "embedded", "seconds": secs, "sha256": sha(out), "copymap": sha(str(out) + ".raw"),
                            "rss": {"texsyn": rss}, "pieces": []})


def run_cluster(args, build, ref, work, nworkers, results, label, frame_limit, server_args=()):
    name = re.sub(r"\W+", "_", label)
    procs, addrs, threads = [], [], 2 if nworkers == 1 else 1
    for i in range(nworkers):
        extra = ["--max-frame", frame_limit] if frame_limit else []
        p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", threads, *extra],
                     work / f"{name}-w{i}.log")
        procs.append(p)
        addrs.append(a)
    server, saddr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", work / f"spool-{name}",
                           "--workers", ",".join(addrs), *server_args], work / f"{name}-server.log")
    try:
        wait_ready(build, saddr, nworkers)
        out, report = work / f"{name}.png", work / f"{name}.json"
        secs, rss = timed([build / "texsyn", *job_args(ref, out, report), "--server", saddr], work / f"{name}.time")
        rss = {"texsyn": rss, "texsyn-server": peak_rss(server.pid),
               **{f"texsyn-worker {i}": peak_rss(p.pid) for i, p in enumerate(procs)}}
    finally:
        stop([server, *procs])
    pieces = []
    for i in range(nworkers):
        for size, n in re.findall(r"from a message of (\d+) bytes in (\d+) pieces", (work / f"{name}-w{i}.log").read_text()):
            pieces.append({"worker": i, "bytes": int(size), "pieces": int(n)})
    results["runs"].append({"label": label, "seconds": secs, "sha256": sha(out), "copymap": sha(str(out) + ".raw"),
                            "rss": rss, "pieces": pieces,
                            "wire_bytes": sum(lv["wire_bytes"] for lv in json.loads(report.read_text())["levels"])})


def cpu_model():
    info = Path("/proc/cpuinfo").read_text()
    return re.search(r"model name\s*:\s*(.*)", info).group(1), info.count("processor\t:")


def mib(b):
    return f"{b / 2**20:,.0f} MiB"


def write_md(args, results, path):
    model, cores = cpu_model()
    total = int(re.search(r"MemTotal:\s+(\d+)", Path("/proc/meminfo").read_text()).group(1)) * 1024
    want = results["runs"][0]
    lines = [
        f"# A {args.side}x{args.side} reference on 1 and 3 workers",
        "",
        f"`bench/big_reference.py` (commit {results['commit']}, {results['date']}). Machine: {model}, {cores} cores,",
        f"{total / 2**30:.0f} GiB, shared with other work while it ran.",
        "",
        f"Reference: `aerial/aero1.jpg` resized to {args.side}x{args.side} RGB with oiiotool (sha256 "
        f"`{results['reference_sha256'][:16]}`). Job: "
        "`texsyn synth --ref big.png --rgb-search --wn 11 --wb 3 --size 32x32 --levels 2` (level 1 searches the "
        f"{args.side // 2}² level, level 0 the {args.side}² one). Workers run with `--max-frame "
        f"{args.frame_limit}` ({args.frame_limit / 2**20:g} MiB), so the level-0 slices travel in pieces; "
        "1 worker has 2 scan threads, 3 workers 1 each, the embedded run 2.",
        "",
        "| run | wall s | output sha256 | same bytes as embedded | peak RSS per process |",
        "|---|---|---|---|---|",
    ]
    for r in results["runs"]:
        same = "yes" if (r["sha256"], r["copymap"]) == (want["sha256"], want["copymap"]) else "**NO**"
        rss = ", ".join(f"{k} {mib(v)}" for k, v in r["rss"].items())
        lines.append(f"| {r['label']} | {r['seconds']:.0f} | `{r['sha256'][:16]}` | {same} (copy map too) | {rss} |")
    lines += ["", "Slice messages the workers took in pieces (their log):", ""]
    for r in results["runs"]:
        if r["pieces"]:
            desc = "; ".join(f"worker {p['worker']}: {p['bytes']:,} bytes in {p['pieces']}" for p in r["pieces"])
            lines.append(f"* {r['label']}: {desc}")
    lines += ["", "Memory available (/proc/meminfo) before each run: " +
              ", ".join(f"{k} {v / 2**30:.1f} GiB" for k, v in results["mem_available"].items()) + "."]
    path.write_text("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", type=Path, default=REPO / "build")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--work", type=Path, default=Path("/tmp/texsyn-big-reference"))
    ap.add_argument("--side", type=int, default=4096)
    ap.add_argument("--frame-limit", type=int, default=16 << 20)
    ap.add_argument("--baseline", type=Path, help="an older build to run the clusters with too")
    args = ap.parse_args()
    args.build, args.out = args.build.resolve(), args.out.resolve()
    args.work.mkdir(parents=True, exist_ok=True)
    ref = args.work / f"big{args.side}.png"
    if not ref.exists():
        subprocess.run(["oiiotool", DATA / "aerial" / "aero1.jpg", "--resize", f"{args.side}x{args.side}", "-o", ref],
                       check=True)
    need = BYTES_PER_PIXEL * args.side * args.side
    results = {"commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                        text=True).stdout.strip(),
               "date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()), "runs": [], "mem_available": {},
               "reference_sha256": sha(ref)}  # oiiotool's resize: outputs compare across runs only with it
    need_memory("embedded", need, results)
    run_embedded(args, ref, args.work, results)
    for n in (1, 3):
        label = f"{n} worker{'s' if n > 1 else ''}"
        need_memory(label, need, results)
        run_cluster(args, args.build, ref, args.work, n, results, label, args.frame_limit)
        if args.baseline:
            need_memory(label + " (baseline)", need, results)
            # Its loads have a fixed deadline (--batch-timeout + 30 s), shorter
            # than a level-0 build here: raised, so its worker is not dropped.
            run_cluster(args, args.baseline.resolve(), ref, args.work, n, results, label + " (baseline build)", 0,
                        ["--batch-timeout", 300])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "big_reference.json").write_text(json.dumps(results, indent=1) + "\n")
    write_md(args, results, args.out / "big_reference.md")
    print((args.out / "big_reference.md").read_text())
    if any(r["sha256"] != results["runs"][0]["sha256"] for r in results["runs"]):
        sys.exit("bench: a cluster run's output differs from the embedded run")


if __name__ == "__main__":
    main()
