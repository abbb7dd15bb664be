#!/usr/bin/python3
"""texsyn stylize against Ebsynth (the public StyLit-family tool, built by
../shared/peers/build-ebsynth.sh as a benchmark peer only), side by side in
one run: the two programs alternate (the order flips every run, so drift in
the machine's speed hits both), 2 threads each, and every output is scored
the same way by `texsyn energy`.

Scenes: texbynum at full size (photo + segmentation -> new segmentation,
Ebsynth's command from ../shared/data/README.md), and the StyLit scene
(4 render-pass guides, weight 0.5 each) at a reduced size given by
--stylit-size: texsyn's search is exact (no PatchMatch yet), and at the
full 1200x912 one run would take the better part of an hour on 2 cores.
The reduced inputs are the full ones resized by oiiotool; the report says
so next to every figure.

Writes bench/results/stylize.{md,json} and the output pictures
bench/results/stylize-SCENE-{texsyn,ebsynth}.png.
Usage: bench/stylize.py --build BUILD --ebsynth PATH [--runs 3] [--quick]
"""
import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
THREADS = 2
ENERGY_STEP = 2


def run(cmd, env=None):
    e = dict(os.environ)
    e.update(env or {})
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, env=e)
    if p.returncode != 0:
        sys.exit(f"bench: {shlex.join(map(str, cmd))} failed ({p.returncode}):\n{p.stderr}")
    return p


def cpu():
    """The model name, and family/model, which a cloud CPU's name can hide."""
    fields = {}
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        k, _, v = line.partition(":")
        fields.setdefault(k.strip(), v.strip())
    return (f"{fields.get('model name')} (family {fields.get('cpu family')}, model {fields.get('model')}), "
            f"{os.cpu_count()} logical CPUs")


def scenes(tmp, stylit_size):
    """(name, note, style, [(src, tgt, weight or None)], texsyn options, ebsynth options)."""
    t = DATA / "texbynum"
    yield ("texbynum", "full size, 320x462",
           t / "source_photo.png", [(t / "source_segment.png", t / "target_segment.png", None)],
           ["--patch-size", 3, "--uniformity", 1000], ["-patchsize", 3, "-uniformity", 1000])
    s = DATA / "stylit"
    small = tmp / "stylit"
    small.mkdir()
    for f in sorted(s.glob("*.png")):
        run(["oiiotool", f, "--resize", stylit_size, "-o", small / f.name])
    guides = [(small / f"source_{g}.png", small / f"target_{g}.png", 0.5)
              for g in ("fullgi", "dirdif", "dirspc", "indirb")]
    yield ("stylit", f"REDUCED from 1200x912 to {stylit_size} (every input: oiiotool IN --resize {stylit_size} "
           f"-o TMP/stylit/IN); not the full-size scene",
           small / "source_style.png", guides, ["--patch-size", 5], [])


def guide_args(guides, guide_flag, weight_flag):
    out = []
    for src, tgt, w in guides:
        out += [guide_flag, src, tgt]
        if w is not None:
            out += [weight_flag, w]
    return out


def commands(build, ebsynth, scene, tmp):
    name, _, style, guides, t_opts, e_opts = scene
    t_out, e_out, report = tmp / f"{name}-texsyn.png", tmp / f"{name}-ebsynth.png", tmp / f"{name}.json"
    texsyn = [build / "texsyn", "stylize", "--style", style, *guide_args(guides, "--guide", "--weight"),
              *t_opts, "--threads", THREADS, "--quiet", "-o", t_out, "--report", report]
    peer = [ebsynth, "-style", style, *guide_args(guides, "-guide", "-weight"), *e_opts,
            "-output", e_out]
    energy = [build / "texsyn", "energy", "--style", style, *guide_args(guides, "--guide", "--weight"),
              "--patch-size", t_opts[1], "--sample", ENERGY_STEP, "--threads", THREADS, "--json"]
    return texsyn, peer, energy, t_out, e_out, report


def shown(cmd, tmp):
    """A command as run, the run's scratch directory written TMP."""
    return shlex.join(map(str, cmd)).replace(str(tmp), "TMP")


def timed(cmd, env=None):
    t0 = time.perf_counter()
    run(cmd, env)
    return time.perf_counter() - t0


def measure(build, ebsynth, scene, runs, tmp, out_dir):
    texsyn, peer, energy, t_out, e_out, report = commands(build, ebsynth, scene, tmp)
    peer_env = {"OMP_NUM_THREADS": str(THREADS)}
    rows = []
    for i in range(runs):
        # Alternate which program goes first, so a slow spell is shared.
        order = [("texsyn", texsyn, None), ("ebsynth", peer, peer_env)]
        if i % 2:
            order.reverse()
        row = {"run": i + 1, "first": order[0][0]}
        for prog, cmd, env in order:
            row[f"{prog}_seconds"] = timed(cmd, env)
        for prog, img in (("texsyn", t_out), ("ebsynth", e_out)):
            row[f"{prog}_energy"] = json.loads(run([*energy, "--image", img]).stdout)
        row["texsyn_nnf_coverage"] = json.loads(report.read_text())["coverage"]
        rows.append(row)
        print(f"  {scene[0]} run {i + 1}: texsyn {row['texsyn_seconds']:.1f} s, ebsynth "
              f"{row['ebsynth_seconds']:.1f} s", flush=True)
    for prog, img in (("texsyn", t_out), ("ebsynth", e_out)):
        shutil.copy(img, out_dir / f"stylize-{scene[0]}-{prog}.png")
    med = lambda k, f=None: statistics.median(r[k] if f is None else r[k][f] for r in rows)
    summary = {
        "scene": scene[0], "size_note": scene[1], "runs": runs,
        "texsyn_seconds_median": med("texsyn_seconds"), "ebsynth_seconds_median": med("ebsynth_seconds"),
        "texsyn_energy_median": med("texsyn_energy", "energy"), "ebsynth_energy_median": med("ebsynth_energy", "energy"),
        "texsyn_coverage_median": med("texsyn_energy", "coverage"),
        "ebsynth_coverage_median": med("ebsynth_energy", "coverage"),
        "texsyn_nnf_coverage_median": med("texsyn_nnf_coverage"),
        "commands": {"texsyn": shown(texsyn, tmp),
                     "ebsynth": f"OMP_NUM_THREADS={THREADS} " + shown(peer, tmp),
                     "energy": shown(energy, tmp) + " --image OUT"},
        "rows": rows,
    }
    summary["wall_ratio_texsyn_over_ebsynth"] = summary["texsyn_seconds_median"] / summary["ebsynth_seconds_median"]
    return summary


def markdown(res):
    lines = ["# texsyn stylize vs Ebsynth", "",
             f"CPU: {res['cpu']}. Date: {res['date']}. Commit: {res['commit']}. "
             f"{THREADS} threads each (Ebsynth: OMP_NUM_THREADS={THREADS}); the two programs alternate, "
             "the order flipping every run; medians over the runs.", "",
             f"Energy: `texsyn energy --sample {ENERGY_STEP}`, the mean exact least guided patch distance "
             "(grey levels per compared value; lower is better) of every 2nd target pixel in x and y. "
             "Coverage: the share of exemplar pixels the best exemplar patches of those samples cover "
             "(both from `texsyn energy`); stylize's own NNF coverage in its own column.", "",
             "| scene | size | runs | texsyn s | Ebsynth s | texsyn / Ebsynth wall | texsyn energy | "
             "Ebsynth energy | texsyn coverage | Ebsynth coverage | texsyn NNF coverage |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in res["scenes"]:
        lines.append(f"| {s['scene']} | {s['size_note']} | {s['runs']} | {s['texsyn_seconds_median']:.2f} | "
                     f"{s['ebsynth_seconds_median']:.2f} | {s['wall_ratio_texsyn_over_ebsynth']:.2f} | "
                     f"{s['texsyn_energy_median']:.4f} | {s['ebsynth_energy_median']:.4f} | "
                     f"{s['texsyn_coverage_median']:.4f} | {s['ebsynth_coverage_median']:.4f} | "
                     f"{s['texsyn_nnf_coverage_median']:.4f} |")
    lines.append("")
    for s in res["scenes"]:
        lines += [f"## {s['scene']} ({s['size_note']})", "", "Per run (seconds; energy):", ""]
        for r in s["rows"]:
            lines.append(f"* run {r['run']} ({r['first']} first): texsyn {r['texsyn_seconds']:.2f} s, "
                         f"energy {r['texsyn_energy']['energy']:.4f}; Ebsynth {r['ebsynth_seconds']:.2f} s, "
                         f"energy {r['ebsynth_energy']['energy']:.4f}")
        lines += ["", "Commands:", "", "```sh", s["commands"]["texsyn"], s["commands"]["ebsynth"],
                  s["commands"]["energy"], "```", "",
                  f"Pictures: `stylize-{s['scene']}-texsyn.png`, `stylize-{s['scene']}-ebsynth.png`.", ""]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--ebsynth", default=os.environ.get("TEXSYN_EBSYNTH"),
                    help="the peer binary (default: $TEXSYN_EBSYNTH)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--stylit-size", default="300x228")
    ap.add_argument("--scenes", default="texbynum,stylit")
    ap.add_argument("--quick", action="store_true", help="one run per scene")
    a = ap.parse_args()
    if not a.ebsynth or not os.access(a.ebsynth, os.X_OK):
        sys.exit("bench: no Ebsynth binary: give --ebsynth PATH or TEXSYN_EBSYNTH "
                 "(build it with ../shared/peers/build-ebsynth.sh DIR)")
    build, out_dir = Path(a.build).resolve(), Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = 1 if a.quick else a.runs
    wanted = a.scenes.split(",")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=REPO).stdout.strip()
    res = {"cpu": cpu(), "date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()), "commit": commit,
           "threads": THREADS, "energy_step": ENERGY_STEP, "scenes": []}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for scene in scenes(tmp, a.stylit_size):
            if scene[0] in wanted:
                res["scenes"].append(measure(build, a.ebsynth, scene, runs, tmp, out_dir))
    (out_dir / "stylize.json").write_text(json.dumps(res, indent=2) + "\n")
    (out_dir / "stylize.md").write_text(markdown(res) + "\n")
    print(markdown(res))


if __name__ == "__main__":
    main()
