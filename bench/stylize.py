#!/usr/bin/python3
"""texsyn stylize against Ebsynth (the public StyLit-family tool, built by
../shared/peers/build-ebsynth.sh as a benchmark peer only), side by side in
one run: the two programs alternate (the order flips every run, so drift in
the machine's speed hits both), 2 threads each, and every output is scored
the same way by `texsyn energy`.

Scenes, both at full size, each program with its own defaults:
  texbynum  photo + segmentation -> new segmentation, 320x462, patch 3
            (texsyn --patch-size 3, Ebsynth -patchsize 3);
  stylit    the StyLit scene, 1200x912, 4 render-pass guides at weight 0.5
            (Ebsynth's command from ../shared/data/README.md).
The uniformity options are left at each program's default: the two are on
different scales (texsyn's U is in grey levels per compared value, Ebsynth's
on a squared-error scale), so no one number means the same in both.

Then a uniformity sweep on the StyLit scene: texsyn with --uniformity 0, the
default (1) and 4, each scored by `texsyn energy`, with stylize's own NNF
coverage and repeated-patch counts from its --nnf field.

Writes bench/results/stylize.{md,json} and the pictures
bench/results/stylize-*.png (downscaled with oiiotool when over ~1 MB; the
StyLit pictures also as full-resolution crops, stylize-*-crop.png).
Usage: bench/stylize.py --build BUILD --ebsynth PATH [--runs 3] [--quick]
"""
import argparse
import collections
import hashlib
import json
import os
import shlex
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from array import array
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
THREADS = 2
PICTURE_LIMIT = 1_000_000       # bytes; larger pictures are downscaled
UNIFORMITIES = (0, None, 4)     # None: the default (1), run without the option
REPEAT_LIMITS = (1, 4, 16)      # "used by more than N target pixels"
PM_TILE = 64                    # TS_PM_TILE, common/search/patchmatch.h
CROP = "400x300+760+260"        # a full-resolution detail of the StyLit scene (the right arm)


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


def loadavg():
    return float(Path("/proc/loadavg").read_text().split()[0])


def png_size(path):
    """(width, height) from a PNG's IHDR chunk."""
    head = Path(path).read_bytes()[:24]
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        sys.exit(f"bench: {path} is not a PNG")
    return struct.unpack(">II", head[16:24])


class Scene:
    def __init__(self, name, note, style, guides, patch, t_opts, e_opts, step):
        self.name, self.note, self.style, self.guides = name, note, style, guides
        self.patch, self.t_opts, self.e_opts, self.step = patch, t_opts, e_opts, step


def scenes():
    t = DATA / "texbynum"
    yield Scene("texbynum", "full size, 320x462, patch 3", t / "source_photo.png",
                [(t / "source_segment.png", t / "target_segment.png", None)], 3,
                ["--patch-size", 3], ["-patchsize", 3], 2)
    s = DATA / "stylit"
    yield Scene("stylit", "full size, 1200x912, patch 5, 4 guides at weight 0.5", s / "source_style.png",
                [(s / f"source_{g}.png", s / f"target_{g}.png", 0.5) for g in ("fullgi", "dirdif", "dirspc", "indirb")],
                5, [], [], 4)


def guide_args(guides, guide_flag, weight_flag):
    out = []
    for src, tgt, w in guides:
        out += [guide_flag, src, tgt]
        if w is not None:
            out += [weight_flag, w]
    return out


def texsyn_cmd(build, sc, out, report, extra=()):
    return [build / "texsyn", "stylize", "--style", sc.style, *guide_args(sc.guides, "--guide", "--weight"),
            *sc.t_opts, *extra, "--threads", THREADS, "--quiet", "-o", out, "--report", report]


def ebsynth_cmd(ebsynth, sc, out):
    return [ebsynth, "-style", sc.style, *guide_args(sc.guides, "-guide", "-weight"), *sc.e_opts, "-output", out]


def energy_cmd(build, sc):
    return [build / "texsyn", "energy", "--style", sc.style, *guide_args(sc.guides, "--guide", "--weight"),
            "--patch-size", sc.patch, "--sample", sc.step, "--threads", THREADS, "--json"]


def shown(cmd, tmp):
    """A command as run, the run's scratch directory written TMP."""
    return shlex.join(map(str, cmd)).replace(str(tmp), "TMP")


def timed(cmd, env=None):
    t0 = time.perf_counter()
    run(cmd, env)
    return time.perf_counter() - t0


def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class Scorer:
    """texsyn energy, once per distinct image (texsyn's output is the same bytes
    every run when the search modes are the same)."""

    def __init__(self, build):
        self.build, self.cache = build, {}

    def __call__(self, sc, img):
        key = (sc.name, sha(img))
        if key not in self.cache:
            t0 = time.perf_counter()
            e = json.loads(run([*energy_cmd(self.build, sc), "--image", img]).stdout)
            e["scoring_seconds"] = round(time.perf_counter() - t0, 1)
            self.cache[key] = e
        return dict(self.cache[key], sha256=key[1][:16])


def report_summary(report):
    r = json.loads(Path(report).read_text())
    return {"nnf_coverage": r["coverage"], "stylize_seconds_reported": r["seconds"],
            "search": [lv["search"] for lv in r["levels"]]}


def nnf_repeats(nnf, source_size, target_size):
    """How often each exemplar pixel is the NNF source of a target pixel."""
    sw, sh = source_size
    tw, th = target_size
    a = array("I")
    a.frombytes(Path(nnf).read_bytes())
    if sys.byteorder != "little":
        a.byteswap()
    if len(a) != 2 * tw * th:
        sys.exit(f"bench: {nnf}: {len(a)} values, expected {2 * tw * th}")
    xs, ys = a[0::2], a[1::2]
    uses = collections.Counter(x + y * sw for x, y in zip(xs, ys))
    n = tw * th
    out = {"distinct_sources": len(uses), "distinct_share_of_exemplar": len(uses) / (sw * sh),
           "max_use": max(uses.values()), "mean_use_rate": n / (sw * sh)}
    for lim in REPEAT_LIMITS:
        out[f"share_used_gt_{lim}"] = sum(c for c in uses.values() if c > lim) / n
    # Coherence: a horizontal neighbour pair is broken when the right pixel's
    # source is not the left one's shifted by one; counted apart where the
    # pair straddles a PatchMatch tile edge.
    broken, pairs = [0, 0], [0, 0]
    for y in range(th):
        r = y * tw
        for x in range(tw - 1):
            i, edge = r + x, int(x % PM_TILE == PM_TILE - 1)
            pairs[edge] += 1
            if xs[i + 1] != xs[i] + 1 or ys[i + 1] != ys[i]:
                broken[edge] += 1
    out["broken_pairs"] = broken[0] / pairs[0]
    out["broken_pairs_at_tile_edges"] = broken[1] / pairs[1] if pairs[1] else None
    return out


def picture(src, dst):
    """Copy a result picture, downscaled by oiiotool when it is over the limit."""
    shutil.copy(src, dst)
    scale = 1.0
    while Path(dst).stat().st_size > PICTURE_LIMIT and scale > 0.2:
        scale *= 0.75
        w, h = png_size(src)
        run(["oiiotool", src, "--resize", f"{round(w * scale)}x{round(h * scale)}", "-o", dst])
    w, h = png_size(dst)
    return f"{dst.name} ({w}x{h}{'' if scale == 1.0 else ', downscaled'})"


def crop(src, dst, region=CROP):
    """A full-resolution detail of a result picture."""
    run(["oiiotool", src, "--cut", region, "-o", dst])
    return f"{dst.name} (full resolution, {region})"


def measure(build, ebsynth, sc, runs, tmp, out_dir, score):
    peer_env = {"OMP_NUM_THREADS": str(THREADS)}
    rows = []
    cmds = {}
    for i in range(1, runs + 1):
        t_out, e_out = tmp / f"{sc.name}-texsyn-{i}.png", tmp / f"{sc.name}-ebsynth-{i}.png"
        report = tmp / f"{sc.name}-{i}.json"
        texsyn, peer = texsyn_cmd(build, sc, t_out, report), ebsynth_cmd(ebsynth, sc, e_out)
        cmds.setdefault("texsyn", shown(texsyn, tmp))
        cmds.setdefault("ebsynth", f"OMP_NUM_THREADS={THREADS} " + shown(peer, tmp))
        # Alternate which program goes first, so a slow spell is shared.
        order = [("texsyn", texsyn, None), ("ebsynth", peer, peer_env)]
        if i % 2 == 0:
            order.reverse()
        row = {"run": i, "first": order[0][0], "loadavg_before": loadavg(),
               "texsyn_out": t_out, "ebsynth_out": e_out}
        for prog, cmd, env in order:
            row[f"{prog}_seconds"] = timed(cmd, env)
        row["ratio"] = row["texsyn_seconds"] / row["ebsynth_seconds"]
        row["texsyn_report"] = report_summary(report)
        rows.append(row)
        print(f"  {sc.name} run {i}: texsyn {row['texsyn_seconds']:.1f} s, ebsynth "
              f"{row['ebsynth_seconds']:.1f} s, ratio {row['ratio']:.3f}", flush=True)
    for row in rows:
        for prog in ("texsyn", "ebsynth"):
            row[f"{prog}_energy"] = score(sc, row.pop(f"{prog}_out"))
    # The pictures come from the run whose ratio is the median one.
    mid = sorted(rows, key=lambda r: r["ratio"])[(len(rows) - 1) // 2]
    pics = {prog: picture(tmp / f"{sc.name}-{prog}-{mid['run']}.png", out_dir / f"stylize-{sc.name}-{prog}.png")
            for prog in ("texsyn", "ebsynth")}
    if sc.name == "stylit":
        for prog in ("texsyn", "ebsynth"):
            pics[prog] += ", " + crop(tmp / f"{sc.name}-{prog}-{mid['run']}.png",
                                      out_dir / f"stylize-{sc.name}-{prog}-crop.png")
    med = lambda f: statistics.median(f(r) for r in rows)
    cmds["energy"] = shown(energy_cmd(build, sc), tmp) + " --image OUT"
    return {
        "scene": sc.name, "size_note": sc.note, "runs": runs, "energy_step": sc.step,
        "texsyn_seconds_median": med(lambda r: r["texsyn_seconds"]),
        "ebsynth_seconds_median": med(lambda r: r["ebsynth_seconds"]),
        "ratio_median": med(lambda r: r["ratio"]),
        "texsyn_energy_median": med(lambda r: r["texsyn_energy"]["energy"]),
        "ebsynth_energy_median": med(lambda r: r["ebsynth_energy"]["energy"]),
        "texsyn_coverage_median": med(lambda r: r["texsyn_energy"]["coverage"]),
        "ebsynth_coverage_median": med(lambda r: r["ebsynth_energy"]["coverage"]),
        "texsyn_nnf_coverage_median": med(lambda r: r["texsyn_report"]["nnf_coverage"]),
        "picture_run": mid["run"], "pictures": pics, "commands": cmds, "rows": rows,
    }


def uniformity_sweep(build, sc, tmp, out_dir, score):
    src_size, tgt_size = png_size(sc.style), png_size(sc.guides[0][1])
    rows, cmds = [], []
    for u in UNIFORMITIES:
        tag = "default" if u is None else str(u)
        out, report, nnf = tmp / f"u-{tag}.png", tmp / f"u-{tag}.json", tmp / f"u-{tag}.raw"
        extra = [] if u is None else ["--uniformity", u]
        cmd = texsyn_cmd(build, sc, out, report, [*extra, "--nnf", nnf])
        cmds.append(shown(cmd, tmp))
        seconds = timed(cmd)
        row = {"uniformity": "1 (default)" if u is None else u, "seconds": seconds,
               **report_summary(report), "energy": score(sc, out), "repeats": nnf_repeats(nnf, src_size, tgt_size)}
        # The default's whole picture is the comparison's texsyn picture (the same job and bytes).
        whole = ("stylize-stylit-texsyn.png (the comparison's texsyn picture: the same run)" if u is None
                 else picture(out, out_dir / f"stylize-stylit-uniformity-{tag}.png"))
        row["picture"] = whole + ", " + crop(out, out_dir / f"stylize-stylit-uniformity-{tag}-crop.png")
        rows.append(row)
        print(f"  uniformity {row['uniformity']}: {seconds:.1f} s, energy {row['energy']['energy']:.4f}, "
              f"coverage {row['energy']['coverage']:.4f}, NNF coverage {row['nnf_coverage']:.4f}", flush=True)
    return {"scene": sc.name, "energy_step": sc.step, "commands": cmds, "rows": rows}


def searches(modes):
    """The per-level search modes, coarsest first, run-length encoded."""
    out = []
    for m in modes:
        if out and out[-1][0] == m:
            out[-1][1] += 1
        else:
            out.append([m, 1])
    return ", ".join(f"{m} x{n}" for m, n in out)


def markdown(res):
    lines = ["# texsyn stylize vs Ebsynth", "",
             f"CPU: {res['cpu']}. Date: {res['date']}. Commit: {res['commit']}. Peer: {res['peer']}. "
             f"{THREADS} threads each (texsyn --threads {THREADS}, Ebsynth OMP_NUM_THREADS={THREADS}); the two "
             "programs alternate, the order flipping every run; medians over the runs, and the median of the "
             "per-run ratios texsyn / Ebsynth wall time. The machine is shared (2 vCPUs, other work running), "
             "so single times are noisy; the load average before each run is listed.", "",
             "Both programs run with their own defaults (search, iterations, uniformity) apart from the patch "
             "size on texbynum and the guide weights; the uniformity settings are on different scales and are "
             "not matched. texsyn's default search is `auto`: exact at the levels whose estimated exact time "
             "at the calibrated rate fits `--budget` (1 s), PatchMatch at the others; the search column shows which ran, coarsest "
             "level first.", "",
             "Energy: `texsyn energy --sample STEP`, the mean exact least guided patch distance (grey levels "
             "per compared value; lower is better) of every STEP-th target pixel in x and y. Coverage: the "
             "share of exemplar pixels the best exemplar patches of those samples cover (both from "
             "`texsyn energy`; compare coverages at one STEP only). NNF coverage: stylize's own, from its "
             "`--report`. Every distinct output image of every run is scored (texsyn's are the same bytes "
             "from run to run when the search modes agree).", "",
             "| scene | runs | texsyn s | Ebsynth s | texsyn / Ebsynth (median of per-run ratios) | energy step | "
             "texsyn energy | Ebsynth energy | texsyn coverage | Ebsynth coverage | texsyn NNF coverage |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in res["scenes"]:
        lines.append(f"| {s['scene']} ({s['size_note']}) | {s['runs']} | {s['texsyn_seconds_median']:.2f} | "
                     f"{s['ebsynth_seconds_median']:.2f} | {s['ratio_median']:.3f} | {s['energy_step']} | "
                     f"{s['texsyn_energy_median']:.4f} | {s['ebsynth_energy_median']:.4f} | "
                     f"{s['texsyn_coverage_median']:.4f} | {s['ebsynth_coverage_median']:.4f} | "
                     f"{s['texsyn_nnf_coverage_median']:.4f} |")
    lines.append("")
    for s in res["scenes"]:
        lines += [f"## {s['scene']} ({s['size_note']})", "", "Per run:", "",
                  "| run | first | load before | texsyn s | Ebsynth s | ratio | texsyn search | texsyn energy | "
                  "Ebsynth energy | texsyn coverage | Ebsynth coverage | texsyn NNF coverage |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in s["rows"]:
            te, ee = r["texsyn_energy"], r["ebsynth_energy"]
            lines.append(f"| {r['run']} | {r['first']} | {r['loadavg_before']:.2f} | {r['texsyn_seconds']:.2f} | "
                         f"{r['ebsynth_seconds']:.2f} | {r['ratio']:.3f} | {searches(r['texsyn_report']['search'])} | "
                         f"{te['energy']:.4f} | {ee['energy']:.4f} | {te['coverage']:.4f} | {ee['coverage']:.4f} | "
                         f"{r['texsyn_report']['nnf_coverage']:.4f} |")
        lines += ["", "Commands (run 1; run N writes `-N` files):", "", "```sh", s["commands"]["texsyn"],
                  s["commands"]["ebsynth"], s["commands"]["energy"], "```", "",
                  f"Pictures (from run {s['picture_run']}, the median ratio): texsyn {s['pictures']['texsyn']}; "
                  f"Ebsynth {s['pictures']['ebsynth']}.", ""]
    u = res.get("uniformity")
    if u:
        lims = REPEAT_LIMITS
        lines += [f"## Uniformity: texsyn on the {u['scene']} scene (full size)", "",
                  f"One run each. Energy and coverage: `texsyn energy --sample {u['energy_step']}` as above. "
                  "NNF coverage: stylize's `--report`. Repeats, from the `--nnf` field (one exemplar centre per "
                  "target pixel): the share of target pixels whose exemplar centre is the centre of more than N "
                  "target pixels (the exemplar and target have the same size, so the average use is "
                  f"{u['rows'][0]['repeats']['mean_use_rate']:.2f}; a patch copied whole maps its pixels to "
                  "distinct centres, so these count literal repetition), the share of exemplar pixels used as a "
                  "centre at all, and the most uses of one centre. Broken pairs: the share of horizontal "
                  "neighbours whose sources are not the left one's shifted by one pixel (0: one coherent copy; "
                  f"high: a field of scattered single pixels), overall and across the {PM_TILE}-pixel PatchMatch "
                  "tile edges.", "",
                  "| uniformity | s | search | energy | coverage | NNF coverage | "
                  + " | ".join(f"used > {n}" for n in lims)
                  + " | exemplar pixels used | max use | broken pairs | at tile edges |",
                  "|---|---|---|---|---|---|" + "---|" * len(lims) + "---|---|---|---|"]
        for r in u["rows"]:
            rp = r["repeats"]
            lines.append(f"| {r['uniformity']} | {r['seconds']:.2f} | {searches(r['search'])} | "
                         f"{r['energy']['energy']:.4f} | {r['energy']['coverage']:.4f} | {r['nnf_coverage']:.4f} | "
                         + " | ".join(f"{rp[f'share_used_gt_{n}']:.4f}" for n in lims)
                         + f" | {rp['distinct_share_of_exemplar']:.4f} | {rp['max_use']} | "
                         f"{rp['broken_pairs']:.4f} | {rp['broken_pairs_at_tile_edges']:.4f} |")
        lines += ["", "Commands:", "", "```sh", *u["commands"], "```", "",
                  "Pictures: " + "; ".join(f"uniformity {r['uniformity']}: {r['picture']}" for r in u["rows"]) + ".", ""]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=str(REPO / "build"))
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--ebsynth", default=os.environ.get("TEXSYN_EBSYNTH"),
                    help="the peer binary (default: $TEXSYN_EBSYNTH)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--scenes", default="texbynum,stylit")
    ap.add_argument("--no-uniformity", action="store_true", help="skip the uniformity sweep")
    ap.add_argument("--quick", action="store_true", help="one run per scene")
    a = ap.parse_args()
    if not a.ebsynth or not os.access(a.ebsynth, os.X_OK):
        sys.exit("bench: no Ebsynth binary: give --ebsynth PATH or TEXSYN_EBSYNTH "
                 "(build it with ../shared/peers/build-ebsynth.sh DIR)")
    if not shutil.which("oiiotool"):
        sys.exit("bench: oiiotool is needed to downscale the pictures")
    build, out_dir = Path(a.build).resolve(), Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = 1 if a.quick else a.runs
    wanted = a.scenes.split(",")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=REPO).stdout.strip()
    res = {"cpu": cpu(), "date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()), "commit": commit,
           "peer": "Ebsynth 2f5c97c (CPU, ../shared/peers/build-ebsynth.sh)", "threads": THREADS, "scenes": []}
    score = Scorer(build)
    with tempfile.TemporaryDirectory(prefix="texsyn-stylize-bench-") as d:
        tmp = Path(d)
        for sc in scenes():
            if sc.name in wanted:
                res["scenes"].append(measure(build, a.ebsynth, sc, runs, tmp, out_dir, score))
            if sc.name == "stylit" and not a.no_uniformity:
                res["uniformity"] = uniformity_sweep(build, sc, tmp, out_dir, score)
    (out_dir / "stylize.json").write_text(json.dumps(res, indent=2, default=str) + "\n")
    (out_dir / "stylize.md").write_text(markdown(res) + "\n")
    print(markdown(res))


if __name__ == "__main__":
    main()
