#!/usr/bin/python3
"""The blend of `texsyn video` between two keys (server/cli/video_blend.c)
against the linear blend by the frame's place that it replaced and against
`texsyn stylize --frames`, on the shot of bench/video_shot.py (issue 27:
"with two keys, no step at the blend larger than 1.5x the sequence's median
step", and no ghosting).

Keys: input frames 1 and N with blurred noise added (seeds 7 and 9), two
independent stroke patterns the frames' colours do not predict, as in
tests/integration/test_video.py. Measured:
  * temporal error: `texsyn flicker` (mean, per step); the steps at the
    blend are those into a frame whose selection changed (its share of the
    backward chain differs from the frame before's), set against the
    sequence's median step;
  * ghosting: `texsyn energy` of each frame between the keys against both
    keys at once (the two paintings side by side as one exemplar, the two
    input frames as its guide): a patch mixing the two keys' strokes
    matches neither, so a cross-fade raises it;
  * the linear blend is made here from the very chain frames video blended
    (kept by --write-guides), rounded as video made it.

usage: bench/video_blend.py [--frames 48] [--size 256x192] [--threads 2]
                            [--sample 2] [--work DIR] [--out bench/results/video-blend]
Writes OUT.json and OUT.md."""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEXSYN = Path(os.environ.get("TEXSYN_BUILD", REPO / "build")) / "texsyn"


def sh(*args, **kw):
    return subprocess.run([str(a) for a in args], check=True, capture_output=True, text=True, **kw)


def read_ppm(path):
    data = Path(path).read_bytes()
    head = data.split(maxsplit=4)
    w, h = int(head[1]), int(head[2])
    return w, h, data[len(data) - w * h * 3:]


def pixels(path, tmp):
    ppm = Path(tmp) / (Path(path).stem + ".ppm")
    sh("oiiotool", path, "-o", ppm)
    return read_ppm(ppm)


def flicker(shot, pattern, frames):
    out = sh(TEXSYN, "flicker", "--frames", frames, "--input", shot / "in_%04d.png", "--image", pattern, "--json")
    return json.loads(out.stdout)


def energy(shot, work, image, t, sample):
    out = sh(TEXSYN, "energy", "--style", work / "keys.png", "--guide", work / "keys_in.png",
             shot / f"in_{t:04d}.png", "--image", image, "--sample", sample, "--quiet")
    return json.loads(out.stdout)["energy"]


def linear_frames(work, g, n):
    """The linear blend of the chains' frames 2..n-1 as lin_%04d.png; 1 and
    n are the keys' own frames."""
    for t in range(1, n + 1):
        if t in (1, n):
            sh("oiiotool", g / f"from_{t:04d}_{t:04d}_out.png", "-o", work / f"lin_{t:04d}.png")
            continue
        w, h, f = pixels(g / f"from_0001_{t:04d}_out.png", work)
        _, _, b = pixels(g / f"from_{n:04d}_{t:04d}_out.png", work)
        span = n - 1
        mix = bytes((x * (n - t) + y * (t - 1) + span // 2) // span for x, y in zip(f, b))
        (work / "lin.ppm").write_bytes(b"P6\n%d %d\n255\n" % (w, h) + mix)
        sh("oiiotool", work / "lin.ppm", "-o", work / f"lin_{t:04d}.png")


def steps_summary(fl, shares):
    steps = [s["error"] for s in fl["per_step"]]
    median = statistics.median(steps)
    # per_step[i] is the step into frame first + 1 + i
    at_blend = [s["error"] for s in fl["per_step"] if shares.get(s["frame"], 0) != shares.get(s["frame"] - 1, 0)]
    worst = max(at_blend) if at_blend else 0.0
    return {"mean": fl["mean"], "median_step": median, "worst_step": max(steps),
            "worst_step_at_blend": worst, "at_blend_over_median": worst / median, "steps": steps}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=48)
    p.add_argument("--size", default="256x192")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--sample", type=int, default=2)
    p.add_argument("--work", type=Path, default=None)
    p.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "video-blend")
    a = p.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="video-blend-"))
    shot, n = work / "shot", a.frames
    w, h = a.size.split("x")
    sh("/usr/bin/python3", REPO / "bench" / "video_shot.py", shot / "in_%04d.png", "--frames", n, "--size", a.size)
    for f, seed in ((1, 7), (n, 9)):
        sh("oiiotool", "--pattern", f"noise:type=uniform:min=-0.5:max=0.5:seed={seed}", f"{w}x{h}", "3",
           "--blur", "3x3", shot / f"in_{f:04d}.png", "--add", "-d", "uint8", "-o", shot / f"key{f}.png")
    sh("oiiotool", shot / "key1.png", shot / f"key{n}.png", "--mosaic", "2x1", "-o", work / "keys.png")
    sh("oiiotool", shot / "in_0001.png", shot / f"in_{n:04d}.png", "--mosaic", "2x1", "-o", work / "keys_in.png")
    frames, threads = f"1..{n}", str(a.threads)

    t0 = time.time()
    sh(TEXSYN, "video", "--input", shot / "in_%04d.png", "--frames", frames, "--key", 1, shot / "key1.png",
       "--key", n, shot / f"key{n}.png", "-o", work / "v_%04d.png", "--write-guides", work / "g",
       "--report", work / "r.json", "--threads", threads, "--quiet")
    video_s = time.time() - t0
    t0 = time.time()
    sh(TEXSYN, "stylize", "--style", shot / "key1.png", "--guide", shot / "in_0001.png", shot / "in_%04d.png",
       "--frames", frames, "-o", work / "s_%04d.png", "--threads", threads, "--quiet")
    stylize_s = time.time() - t0
    linear_frames(work, work / "g", n)

    blend = json.loads((work / "r.json").read_text())["blend"]
    shares = {f["frame"]: f["backward"] for f in blend["frames"]}
    shares[n] = 1.0  # the last key's own frame
    runs = {"video (error-driven selection, screened Poisson)": work / "v_%04d.png",
            "video, chains blended linearly by place": work / "lin_%04d.png",
            "stylize --frames, key 1": work / "s_%04d.png"}
    results = {}
    for name, pattern in runs.items():
        r = steps_summary(flicker(shot, pattern, frames), shares)
        es = [energy(shot, work, Path(str(pattern) % t), t, a.sample) for t in range(2, n)]
        r["two_key_energy_mean"] = statistics.mean(es)
        r["two_key_energy_mid"] = es[len(es) // 2]
        results[name] = r
    for k, rng in ((1, f"1..{n - 1}"), (n, f"2..{n}")):
        fl = flicker(shot, work / "g" / f"from_{k:04d}_%04d_out.png", rng)
        es = [energy(shot, work, work / "g" / f"from_{k:04d}_{t:04d}_out.png", t, a.sample) for t in range(2, n)]
        results[f"chain from key {k} alone ({rng})"] = {"mean": fl["mean"],
                                                        "median_step": statistics.median(s["error"] for s in fl["per_step"]),
                                                        "two_key_energy_mean": statistics.mean(es)}
    cpu = next((l.split(":", 1)[1].strip() for l in sh("lscpu").stdout.splitlines() if l.startswith("Model name")), "?")
    out = {"shot": f"bench/video_shot.py, {n} frames {a.size}, keys 1 and {n} (noise seeds 7, 9)",
           "cpu": cpu, "threads": a.threads, "load": os.getloadavg()[0], "energy_sample": a.sample,
           "seconds": {"video": video_s, "stylize_frames": stylize_s}, "blend": blend, "results": results}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")
    lines = [f"# texsyn video: the blend between two keys\n",
             f"{out['shot']}; default stylize parameters, {a.threads} threads; {cpu}, load {out['load']:.1f}. "
             f"Made by `bench/video_blend.py`.\n",
             "Temporal error: `texsyn flicker`. Steps at the blend: into frames whose selection changed. "
             f"Two-key energy: `texsyn energy` (--sample {a.sample}) of frames 2..{n - 1} against both keys "
             "side by side as one exemplar, with the two input frames as its guide: a ghost (two keys' strokes "
             "mixed) matches neither key and raises it.\n",
             "| run | flicker mean | median step | worst step | worst step at the blend / median | "
             "two-key energy, mean (mid frame) |", "| --- | --- | --- | --- | --- | --- |"]
    for name, r in results.items():
        if "worst_step" in r:
            lines.append(f"| {name} | {r['mean']:.2f} | {r['median_step']:.2f} | {r['worst_step']:.2f} | "
                         f"{r['worst_step_at_blend']:.2f} / {r['median_step']:.2f} = {r['at_blend_over_median']:.2f}x"
                         f" | {r['two_key_energy_mean']:.2f} ({r['two_key_energy_mid']:.2f}) |")
        else:
            lines.append(f"| {name} | {r['mean']:.2f} | {r['median_step']:.2f} | - | - | "
                         f"{r['two_key_energy_mean']:.2f} |")
    lines.append(f"\nWall time: video {video_s:.0f} s, stylize --frames {stylize_s:.0f} s.\n")
    a.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
