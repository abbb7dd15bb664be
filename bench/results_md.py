#!/usr/bin/python3
"""Assembles bench/results/RESULTS.md from what the benchmark scripts wrote
(their .md tables and .json figures, their .png plots): the machine (CPU
family/model, cores, date, commit), then one section per benchmark with
its tables, its plots embedded and the command that regenerates it.

  results_md.py --stamp NAME [--mode quick|full]   records that NAME's
        results were just made (date, commit, mode) in stamps.json;
        bench/run.sh calls it after every script;
  results_md.py                                    writes RESULTS.md.

A section whose files are missing says so and how to produce them; every
section prints the date and commit its figures were made at, and flags
those made at another commit than the current one, so no old figure
passes for new.
Usage: bench/results_md.py [--out DIR] [--stamp NAME [--mode M]]
"""
import argparse
import json
import os
import subprocess
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RUN = "/usr/bin/python3 bench/{} --build build --out bench/results [--quick]"

# (stamp name, title, the files it writes that must exist, plots, command)
SECTIONS = [
    ("roofline", "Kernel throughput per SIMD variant against the memory bandwidth (roofline)",
     ["roofline.md", "kernels.csv"], ["roofline.png"],
     "build/bench/bench_kernels --csv bench/results/kernels.csv && /usr/bin/python3 bench/roofline.py"),
    ("table33", "The seed's Table 3.3, column by column", ["table33.md", "table33.json"],
     ["table33.png", "table33-totals.png"], RUN.format("table33.py")),
    ("scaling", "Scaling over 1..16 workers: Table 3.3 job, aerial scene, StyLit scene", ["scaling.md", "scaling.json"],
     ["scaling.png"], RUN.format("scaling.py")),
    ("scaling_aerial", "The large aerial job on 1 and 2 workers (2048^2, catalogue grown to 448^2)",
     ["scaling-aerial.md", "scaling-aerial.json"], ["scaling-aerial.png"],
     "/usr/bin/python3 bench/scaling.py --build build --out bench/results --jobs aerial --workers 1,2 --reps 3 "
     "--name scaling-aerial"),
    ("stylize", "Stylization: texsyn stylize against Ebsynth", ["stylize.md", "stylize.json"],
     ["stylize-stylit-texsyn.png", "stylize-stylit-ebsynth.png"],
     "/usr/bin/python3 bench/stylize.py --build build --out bench/results --ebsynth PATH [--quick]"),
    ("copy_accel", "The copy-map shortcut on the Table 3.3 job", ["copy-accel.md", "copy-accel.json"], [],
     RUN.format("copy_accel.py")),
    ("lbg", "LBG partitioning against the exact search", ["lbg.md", "lbg.json"], [], RUN.format("lbg.py")),
    ("cluster", "Cluster overhead: embedded against loopback clusters", ["cluster.txt", "cluster.json"],
     ["cluster.png"], RUN.format("cluster.py")),
    ("wire", "Bytes on the wire per query", ["wire.md", "wire.json"], [], RUN.format("wire.py")),
    ("latency", "Answer times under load", ["latency.md", "latency.json"], [], RUN.format("latency.py")),
    ("netem", "Emulated networks (netem)", ["netem.md", "netem.json"], [],
     "/usr/bin/python3 bench/netem.py --build build --out bench/results"),
    ("sequence", "A stylization sequence against separate jobs", ["sequence.md", "sequence.json"], [],
     RUN.format("sequence.py")),
    ("segment", "Texture segmentation: accuracy and time", ["segment.md", "segment.json"], [],
     RUN.format("segment.py")),
    ("aerial", "Hole filling and aerial scenes", ["aerial.md", "aerial.json"], ["aerial-2048.png"],
     RUN.format("aerial.py")),
    ("mix", "Texture mixing", ["mix.md"], ["mix-brick.png", "mix-aerial.png"], RUN.format("mix.py")),
    ("video", "Video with keyframes: texsyn video against stylize --frames and Ebsynth frame by frame",
     ["video.md", "video.json"], ["video-strip-noise.png", "video-strip-painting.png"],
     "/usr/bin/python3 bench/video.py --build build --out bench/results --ebsynth PATH --pool [--quick]"),
    ("seal_cost", "Sealed frames: the Table 3.3 job on 3 workers against a build without them",
     ["seal_cost.md", "seal_cost.json"], [],
     "/usr/bin/python3 bench/seal_cost.py --base BASE_BUILD --build build --reps 5 --json bench/results/seal_cost.json"),
    ("tile_seams", "Aerial tiles: borders against interior pairs", ["tile_seams.md", "tile_seams.json"],
     ["tile_seams-crop.png"], "/usr/bin/python3 bench/tile_seams.py --build build"),
    ("bigtiff", "A GeoTIFF past 4 GiB through the GIS writer", ["bigtiff.md"], [],
     "/usr/bin/python3 bench/bigtiff.py --build build"),
    ("video_blend", "The blend between two keys: steps at the seam, ghosting", ["video-blend.md", "video-blend.json"],
     ["video-blend-strip-painting.png"], RUN.format("video_blend.py")),
]

# What the command line cannot say: where a section's prerequisites come from.
NOTES = {
    "stylize": "PATH: the Ebsynth peer, built by `../shared/peers/build-ebsynth.sh DIR` as DIR/ebsynth; "
               "`TEXSYN_EBSYNTH=DIR/ebsynth make bench` runs it.",
    "netem": "`make bench-netem` or `make bench-full` runs it.",
    "aerial": "`make bench-full` runs it.",
    "video": "PATH: the Ebsynth peer, as for the stylization section; `TEXSYN_EBSYNTH=DIR/ebsynth make bench-full` "
             "runs it.",
    "video_blend": "`make bench-full` runs it.",
    "seal_cost": "BASE_BUILD: a build of the commit before sealed frames (protocol 6), e.g. 428eedf.",
    "scaling_aerial": "The scaling section of `make bench-full` runs the same job over 1 to 16 workers; this "
                      "command runs it on 1 and 2 alone (about 9 minutes).",
}


def git(*args):
    p = subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True)
    return p.stdout.strip() if p.returncode == 0 else "unknown"


def commit():
    head = git("rev-parse", "--short", "HEAD")
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!bench/results")
    return head + ("-dirty" if dirty and dirty != "unknown" else "")


def cpuinfo():
    fields = {}
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        k, _, v = line.partition(":")
        fields.setdefault(k.strip(), v.strip())
    flags = sorted(set(fields.get("flags", "").split()) & {"avx2", "avx512bw", "avx512_vnni"})
    return (f"{fields.get('model name', 'unknown')}, family {fields.get('cpu family', '?')}, model "
            f"{fields.get('model', '?')} ({' '.join(flags) or 'no AVX2'})")


def stamp(out, name, mode):
    path = out / "stamps.json"
    stamps = json.loads(path.read_text()) if path.exists() else {}
    stamps[name] = {"date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()), "commit": commit(), "mode": mode,
                    "loadavg": os.getloadavg()[0]}
    path.write_text(json.dumps(stamps, indent=1, sort_keys=True) + "\n")


def demote(md):
    """A script's markdown inside a section: its headings one level down."""
    return "\n".join("##" + line if line.startswith("#") else line for line in md.splitlines())


def section(out, stamps, head, name, title, files, plots, command):
    lines = [f"## {title}", "", f"Regenerate: `{command}`" + (f" ({NOTES[name]})" if name in NOTES else ""), ""]
    missing = [f for f in files if not (out / f).exists()]
    if missing:
        return lines + [f"**Not measured**: {', '.join(missing)} missing. Run the command above "
                        "(or `make bench-full`)." + (" It needs the Ebsynth peer." if name == "stylize" else ""), ""]
    st = stamps.get(name)
    if st:
        old = "" if st["commit"] == head else f" — **made at another commit than this file ({head})**"
        lines += [f"_Made {st['date']} at commit {st['commit']} ({st['mode']} mode, load average "
                  f"{st['loadavg']:.2f} at the end){old}._", ""]
    else:  # a file's date on disk is its checkout's: the commit that last changed it tells more
        last = git("log", "-1", "--format=%h %cd", "--date=format:%Y-%m-%d", "--", str((out / files[0]).resolve()))
        where = f"last committed at {last}" if last and last != "unknown" else "never committed, date unknown"
        lines += [f"_No stamp ({where}): figures of an earlier run, **possibly stale**, not regenerated by this "
                  "one; rerun the command._", ""]
    body = (out / files[0]).read_text()
    lines += ["```", body.rstrip(), "```", ""] if files[0].endswith(".txt") else [demote(body).rstrip(), ""]
    for p in plots:
        if (out / p).exists():
            lines += [f"![{title}: {p}]({p})", ""]
        else:
            lines += [f"_Plot {p} missing (gnuplot not installed? `deploy/install-deps.sh --bench`)._", ""]
    return lines


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--stamp", help="record that this benchmark's results were just made")
    ap.add_argument("--mode", default="quick", choices=["quick", "full"])
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.stamp:
        if a.stamp not in {s[0] for s in SECTIONS}:
            raise SystemExit(f"bench: unknown section {a.stamp!r}; the sections are "
                             f"{', '.join(s[0] for s in SECTIONS)}")
        stamp(out, a.stamp, a.mode)
        return
    stamps_path = out / "stamps.json"
    stamps = json.loads(stamps_path.read_text()) if stamps_path.exists() else {}
    head = commit()
    lines = ["# texsyn benchmark results", "",
             f"Machine: {cpuinfo()}; **{os.cpu_count()} cores** (nproc), {os.uname().machine}. "
             f"Assembled {time.strftime('%Y-%m-%dT%H:%MZ', time.gmtime())} at commit {head} by "
             "`bench/results_md.py` (`make bench`: quick, `make bench-full`: everything). "
             "Every figure is a median of several runs with its spread; ratios are taken inside one run. "
             "Each section says when and at which commit its figures were made, and the 1-minute load average "
             "when it finished (the benchmark's own threads included: well above 2 means other work ran "
             "alongside, figures under load).", ""]
    for name, title, files, plots, command in SECTIONS:
        lines += section(out, stamps, head, name, title, files, plots, command)
    (out / "RESULTS.md").write_text("\n".join(lines) + "\n")
    print(f"bench: wrote {out / 'RESULTS.md'}")


if __name__ == "__main__":
    main()
