#!/usr/bin/python3
"""Constrained synthesis at scale (seed 002 §3.2, §5.1): hole filling and
aerial scenes, embedded and on a 3-worker loopback cluster.

Hole filling: textures/brick.png and aerial/aero1.jpg with masks of several
shapes (a rectangle, a disc, a thin stroke, scattered squares), embedded and
on 3 workers; the pictures (input with the hole shown, result) go to
bench/results/fill-*.png for judging the seams, and the bytes are compared.

Aerial: a class map with roads (bench/mkscene) at each --sizes, references
cut from aero1.jpg (bench/aerial_refs.sh): wall seconds and peak memory
(the process's, or the coordinator's and each worker's high-water mark)
embedded and on 3 workers of one thread, the bytes compared, and at the
smallest size a worker killed mid-job. Writes bench/results/aerial.md/.json.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cluster import start, stop, wait_ready  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))


def oiiotool(*args):
    subprocess.run(["oiiotool", *map(str, args)], check=True, capture_output=True, timeout=600)


def cpu():
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def hwm_mib(pid):
    """A live process's peak resident memory (VmHWM), MiB."""
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return 0.0


def embedded(build, args, out):
    """Runs texsyn in-process; (seconds, peak MiB of that process)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t = time.time()
    p = subprocess.run([str(build / "texsyn"), *map(str, args), "-o", str(out), "--quiet"], capture_output=True,
                       text=True)
    if p.returncode != 0:
        sys.exit(f"bench: {args} failed: {p.stderr}")
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return time.time() - t, (peak if peak > before else before) / 1024


class Pool:
    """A coordinator and n one-thread workers on loopback."""

    def __init__(self, build, tmp, n, modbus=False):
        self.build, self.procs = build, []
        addrs = []
        for i in range(n):
            extra = ["--modbus", "0"] if modbus else []
            p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1, *extra],
                         tmp / f"w{i}.log")
            self.procs.append(p)
            addrs.append(a)
        p, self.addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / f"spool{time.time()}",
                              "--workers", ",".join(addrs)], tmp / "server.log")
        self.server = p
        wait_ready(build, self.addr, n)

    def run(self, args, out):
        t = time.time()
        p = subprocess.run([str(self.build / "texsyn"), *map(str, args), "-o", str(out), "--quiet", "--server",
                            self.addr], capture_output=True, text=True)
        if p.returncode != 0:
            sys.exit(f"bench: {args} on the cluster failed: {p.stderr}")
        return time.time() - t

    def peaks(self):
        return {"coordinator": hwm_mib(self.server.pid), "workers": [hwm_mib(p.pid) for p in self.procs]}

    def down(self):
        stop([*self.procs, self.server])


def masks(d, w, h):
    """Masks of several shapes for a w x h image."""
    shapes = {
        "rect": ["--fill:color=1", f"{w // 3}x{h // 4}+{w // 3}+{h // 3}"],
        "stroke": ["--fill:color=1", f"{max(6, w // 40)}x{h // 2}+{w // 5}+{h // 6}",
                   "--fill:color=1", f"{w // 2}x{max(6, h // 40)}+{w // 5}+{2 * h // 3}"],
        "squares": [a for i in range(6) for a in ("--fill:color=1", f"{w // 12}x{w // 12}+{(i * 97) % (w - w // 12)}"
                                                  f"+{(i * 61 + 13) % (h - w // 12)}")],
    }
    out = {}
    for name, ops in shapes.items():
        oiiotool("--create", f"{w}x{h}", "1", *ops, "-d", "uint8", "-o", d / f"mask-{name}.png")
        out[name] = d / f"mask-{name}.png"
    return out


def holes(build, tmp, res):
    rows = []
    images = {"brick": DATA / "textures/brick.png", "aero1": DATA / "aerial/aero1.jpg"}
    pool = Pool(build, tmp, 3)
    try:
        for name, img in images.items():
            info = subprocess.run(["oiiotool", "--info", str(img)], capture_output=True, text=True).stdout
            w, h = (int(v) for v in info.split(":")[1].split(",")[0].split("x"))
            for shape, mask in masks(tmp, w, h).items():
                args = ["synth", "--input", img, "--mask", mask, "--levels", 4]
                e, c = tmp / f"e-{name}-{shape}.png", tmp / f"c-{name}-{shape}.png"
                te, _ = embedded(build, args, e)
                tc = pool.run(args, c)
                same = e.read_bytes() == c.read_bytes()
                pic = res / f"fill-{name}-{shape}.png"
                oiiotool(img, "--ch", "R,G,B" if "aero" in name else "0,0,0", mask, "--ch", "0,0,0", "--mulc", "0.6",
                         "--add", "--clamp", e, "--ch", "R,G,B" if "aero" in name else "0,0,0", "--mosaic", "2x1",
                         "-d", "uint8", "-o", pic)
                rows.append({"image": name, "mask": shape, "embedded_s": round(te, 2), "cluster3_s": round(tc, 2),
                             "identical": same, "picture": pic.name})
                print(f"fill {name} {shape}: embedded {te:.2f}s, 3 workers {tc:.2f}s, identical {same}", flush=True)
    finally:
        pool.down()
    return rows


def kill_mid_job(build, tmp, args, want, seconds):
    """The job on 3 workers with worker 2 killed a third of `seconds` (the
    embedded run's time) in: whether the bytes stay."""
    pool = Pool(build, tmp, 3)
    try:
        victim = pool.procs[1]
        out = tmp / "killed.png"
        job = subprocess.Popen([str(build / "texsyn"), *map(str, args), "-o", str(out), "--quiet", "--server",
                                pool.addr], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        time.sleep(seconds / 3)
        victim.kill()
        victim.wait()
        pool.procs.remove(victim)
        _, err = job.communicate(timeout=3600)
        if job.returncode != 0:
            sys.exit(f"bench: the killed-worker job failed: {err}")
        return out.read_bytes() == want
    finally:
        pool.down()


def aerials(build, tmp, res, sizes):
    rows = []
    for size in sizes:
        d = tmp / f"scene{size}"
        d.mkdir()
        subprocess.run([str(build / "bench/mkscene"), "--size", str(size), "--seed", "7", "-o", str(d / "scene")],
                       check=True, capture_output=True)
        subprocess.run(["bash", str(REPO / "bench/aerial_refs.sh"), str(d)], check=True, capture_output=True)
        args = ["aerial", "--classes", d / "scene-classes.png", "--catalogue", d / "catalogue.json"]
        e, c = d / "embedded.png", d / "cluster.png"
        te, pe = embedded(build, args + ["--report", d / "e.json"], e)
        pool = Pool(build, tmp, 3)
        try:
            tc = pool.run(args, c)
            peaks = pool.peaks()
        finally:
            pool.down()
        same = e.read_bytes() == c.read_bytes()
        report = json.loads((d / "e.json").read_text())
        row = {"size": size, "embedded_s": round(te, 1), "embedded_peak_mib": round(pe),
               "cluster3_s": round(tc, 1), "coordinator_peak_mib": round(peaks["coordinator"]),
               "worker_peak_mib": [round(v) for v in peaks["workers"]], "identical": same,
               "blocks": sum(lv["blocks"] for lv in report["levels"]),
               "steps": sum(lv["steps"] for lv in report["levels"])}
        if size == min(sizes):
            row["killed_worker_identical"] = kill_mid_job(build, tmp, args, e.read_bytes(), te)
        oiiotool(e, "--resize", "1024x1024", "-o", res / f"aerial-{size}.png")
        if size == min(sizes):
            oiiotool(d / "scene-classes.png", "--mulc", "60", "-d", "uint8", "-o", res / f"aerial-{size}-classes.png")
            oiiotool(e, "--cut", "512x512+0+0", "-o", res / f"aerial-{size}-detail.png")
        rows.append(row)
        print(f"aerial {size}: {row}", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--sizes", default="2048,8192")
    ap.add_argument("--quick", action="store_true", help="2048 only")
    a = ap.parse_args()
    build, res = Path(a.build).resolve(), Path(a.out)
    res.mkdir(parents=True, exist_ok=True)
    sizes = [2048] if a.quick else [int(s) for s in a.sizes.split(",")]
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        fills = holes(build, tmp, res)
        scenes = aerials(build, tmp, res, sizes)
    result = {"cpu": cpu(), "cores": os.cpu_count(), "fill": fills, "aerial": scenes}
    (res / "aerial.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"# Hole filling and aerial scenes\n", f"CPU: {result['cpu']}, {result['cores']} cores. "
             "Embedded: 2 scan threads; cluster: a coordinator and 3 workers of 1 thread on loopback, all on "
             "the same cores.\n", "## Hole filling (texsyn synth --input --mask, --levels 4)\n",
             "| image | mask | embedded s | 3 workers s | identical | picture (input with the hole / result) |",
             "|---|---|---|---|---|---|"]
    for r in fills:
        lines.append(f"| {r['image']} | {r['mask']} | {r['embedded_s']} | {r['cluster3_s']} | {r['identical']} | "
                     f"{r['picture']} |")
    lines += ["", "## Aerial scenes (texsyn aerial, defaults: levels 3, W_N 7, W_B 3)\n",
              "| size | blocks | steps | embedded s | embedded peak MiB | 3 workers s | coordinator peak MiB | "
              "worker peak MiB | identical | worker killed: identical |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in scenes:
        lines.append(f"| {r['size']}x{r['size']} | {r['blocks']} | {r['steps']} | {r['embedded_s']} | "
                     f"{r['embedded_peak_mib']} | {r['cluster3_s']} | {r['coordinator_peak_mib']} | "
                     f"{', '.join(map(str, r['worker_peak_mib']))} | {r['identical']} | "
                     f"{r.get('killed_worker_identical', '')} |")
    (res / "aerial.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
