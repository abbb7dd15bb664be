"""texsyn stylize on a small synthetic scene made from aero1.jpg (a test image
every machine has, tests/test-data.sh): the style is a 64x48 crop, its guide
the crop's blurred luminance, the target guide that guide mirrored. Checked:
every NNF entry is a source patch centre and the output is exactly the vote
of its NNF; the same bytes for any thread count and on a cluster; uniformity
raises the exemplar coverage; every size and channel mismatch in one error.
The energy of an image: the same output in-process and on a cluster, its
errors on either, and a queued energy job surviving a coordinator restart.
"""
import json
import re
import struct
import subprocess

import pytest

from conftest import BUILD, jobs_listed, modbus_registers, run
from pnm import oiiotool, read_pnm

PATCH = 5


@pytest.fixture(scope="module")
def scene(data, tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    oiiotool(data / "aerial/aero1.jpg", "--cut", "128x96+200+150", "--resize", "64x48", "-o", d / "style.png")
    oiiotool(d / "style.png", "--chsum:weight=.3,.59,.11", "--blur", "3x3", "-o", d / "src.png")
    oiiotool(d / "src.png", "--flop", "-o", d / "tgt.png")
    oiiotool(d / "style.png", "-o", d / "style.ppm")
    return d


def stylize(texsyn, scene, out, *extra, check=True):
    return run(texsyn, "stylize", "--style", scene / "style.png", "--guide", scene / "src.png", scene / "tgt.png",
               "-o", out, "--quiet", "--iters", "3", *extra, check=check)


def test_output_is_the_vote_of_its_nnf(texsyn, scene, tmp_path):
    out, nnf = tmp_path / "out.png", tmp_path / "nnf.raw"
    stylize(texsyn, scene, out, "--nnf", nnf)
    oiiotool(out, "-o", tmp_path / "out.ppm")
    sw, sh, ch, style = read_pnm(scene / "style.ppm")
    tw, th, och, got = read_pnm(tmp_path / "out.ppm")
    assert (tw, th, och) == (64, 48, ch)
    pairs = struct.unpack(f"<{2 * tw * th}I", nnf.read_bytes())
    r = PATCH // 2
    for i in range(tw * th):
        assert r <= pairs[2 * i] < sw - r and r <= pairs[2 * i + 1] < sh - r, f"pixel {i}: no source patch there"
    for y in range(th):
        for x in range(tw):
            sums, n = [0] * ch, 0
            for cy in range(max(0, y - r), min(th, y + r + 1)):
                for cx in range(max(0, x - r), min(tw, x + r + 1)):
                    sx = pairs[2 * (cy * tw + cx)] + x - cx
                    sy = pairs[2 * (cy * tw + cx) + 1] + y - cy
                    for c in range(ch):
                        sums[c] += style[(sy * sw + sx) * ch + c]
                    n += 1
            want = bytes((s + n // 2) // n for s in sums)
            assert got[(y * tw + x) * ch:(y * tw + x + 1) * ch] == want, f"pixel ({x}, {y}) is not its vote"


@pytest.mark.sanitize
@pytest.mark.parametrize("search", ["exact", "patchmatch"])
def test_same_bytes_for_any_thread_count_and_on_a_cluster(texsyn, scene, cluster, tmp_path, search):
    outs = []
    for name, where in (("t1", ["--threads", "1"]), ("t3", ["--threads", "3"])):
        stylize(texsyn, scene, tmp_path / f"{name}.png", "--nnf", tmp_path / f"{name}.raw", "--search", search,
                *where)
        outs.append(name)
    cluster.start(2, 1)
    stylize(texsyn, scene, tmp_path / "c.png", "--nnf", tmp_path / "c.raw", "--search", search,
            "--server", cluster.server.addr)
    outs.append("c")
    for name in outs[1:]:
        assert (tmp_path / f"{name}.png").read_bytes() == (tmp_path / "t1.png").read_bytes(), name
        assert (tmp_path / f"{name}.raw").read_bytes() == (tmp_path / "t1.raw").read_bytes(), name


def test_patchmatch_keeps_its_bytes_when_a_worker_is_killed_mid_job(texsyn, data, cluster, tmp_path):
    """A 256x192 scene in patchmatch on 3 workers: one is killed once it
    holds a patchmatch source (the passes of a level are under way); the
    others sweep its tiles again and the result is the embedded bytes."""
    d = tmp_path
    oiiotool(data / "aerial/aero1.jpg", "--cut", "512x384+100+100", "--resize", "256x192", "-o", d / "style.png")
    oiiotool(d / "style.png", "--chsum:weight=.3,.59,.11", "--blur", "3x3", "-o", d / "src.png")
    oiiotool(d / "src.png", "--flop", "-o", d / "tgt.png")
    args = ["stylize", "--style", d / "style.png", "--guide", d / "src.png", d / "tgt.png", "--search", "patchmatch",
            "--pm-iters", "8", "--quiet"]
    run(texsyn, *args, "-o", d / "embedded.png", "--nnf", d / "embedded.raw", "--threads", "2")
    cluster.start(3, 1)
    job = subprocess.Popen([str(texsyn), *map(str, args), "-o", d / "c.png", "--nnf", d / "c.raw",
                            "--server", cluster.server.addr], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    victim = cluster.workers[1]
    victim.wait_log(r"patchmatch source \d+")
    assert job.poll() is None, "the job ended before the worker was killed"
    victim.proc.kill()
    out, err = job.communicate(timeout=600)
    assert job.returncode == 0, err
    cluster.server.wait_log(r"worker 2 \(\S+\) dropped")
    assert (d / "c.png").read_bytes() == (d / "embedded.png").read_bytes()
    assert (d / "c.raw").read_bytes() == (d / "embedded.raw").read_bytes()


def test_uniformity_raises_the_exemplar_coverage(texsyn, scene, tmp_path):
    coverage = {}
    for u in ("0", "4"):
        report = tmp_path / f"u{u}.json"
        stylize(texsyn, scene, tmp_path / f"u{u}.png", "--uniformity", u, "--report", report)
        coverage[u] = json.loads(report.read_text())["coverage"]
    assert coverage["4"] > coverage["0"] + 0.05, coverage


def test_every_mismatch_in_one_error(texsyn, scene, tmp_path):
    oiiotool(scene / "src.png", "--resize", "32x24", "-o", tmp_path / "small.png")
    oiiotool(scene / "style.png", "-o", tmp_path / "rgb.png")
    p = run(texsyn, "stylize", "--style", scene / "style.png",
            "--guide", tmp_path / "small.png", scene / "tgt.png",
            "--guide", scene / "src.png", tmp_path / "small.png",
            "--guide", scene / "src.png", tmp_path / "rgb.png",
            "--patch-size", "4", "-o", tmp_path / "x.png", check=False)
    assert p.returncode == 2
    for line in ("--patch-size 4: need an odd number",
                 "guide 1: its source is 32x24, the style 64x48",
                 "guide 2: its target is 32x24, guide 1's 64x48",
                 "guide 3: its source has 1 channels, its target 3"):
        assert line in p.stderr, p.stderr
    assert not (tmp_path / "x.png").exists()


def test_apply_nnf_to_the_style_gives_the_output(texsyn, scene, tmp_path):
    """Both NNF files stylize writes (.raw, and the 16-bit image) voted over
    the exemplar give the stylize output byte for byte; a .raw NNF of the
    wrong size is refused, naming --size."""
    for name in ("nnf.raw", "nnf.png"):
        out = tmp_path / f"out-{name}.png"
        stylize(texsyn, scene, out, "--nnf", tmp_path / name)
        size = ["--size", "64x48"] if name.endswith(".raw") else []
        run(texsyn, "apply-nnf", "--nnf", tmp_path / name, "--source", scene / "style.png",
            "-o", tmp_path / f"again-{name}.png", *size)
        oiiotool(out, "-o", tmp_path / "a.ppm")
        oiiotool(tmp_path / f"again-{name}.png", "-o", tmp_path / "b.ppm")
        assert (tmp_path / "a.ppm").read_bytes() == (tmp_path / "b.ppm").read_bytes(), name
    p = run(texsyn, "apply-nnf", "--nnf", tmp_path / "nnf.raw", "--source", scene / "style.png",
            "-o", tmp_path / "x.png", "--size", "64x47", check=False)
    assert p.returncode == 2 and "is --size right?" in p.stderr, p.stderr


def test_energy_prints_json_as_quality_does(texsyn, scene, tmp_path):
    """One JSON object, with --json or without, counting every 2nd pixel in x and y; the
    exemplar scored as its own stylization (target guide = source guide)
    beats a stylize output; a grey image for an RGB style and a --guide
    without its TGT are refused."""
    out = tmp_path / "out.png"
    stylize(texsyn, scene, out)
    args = ["energy", "--style", scene / "style.png", "--guide", scene / "src.png", scene / "tgt.png",
            "--image", out, "--sample", "2"]
    printed = run(texsyn, *args).stdout
    assert run(texsyn, *args, "--json").stdout == printed  # JSON, as quality prints, with or without --json
    got = json.loads(printed)
    assert got["samples"] == 32 * 24 and got["step"] == 2
    assert 0 < got["energy"] and 0 < got["coverage"] <= 1
    copy = run(texsyn, "energy", "--style", scene / "style.png", "--guide", scene / "src.png", scene / "src.png",
               "--image", scene / "style.png", "--json").stdout
    assert json.loads(copy)["energy"] < got["energy"]
    p = run(texsyn, "energy", "--style", scene / "style.png", "--guide", scene / "src.png", scene / "tgt.png",
            "--image", scene / "src.png", check=False)
    assert p.returncode == 2 and "--image" in p.stderr, p.stderr
    p = run(texsyn, "energy", "--style", scene / "style.png", "--guide", scene / "src.png", "--image", out, check=False)
    assert p.returncode == 2 and "needs a target guide after it" in p.stderr, p.stderr


@pytest.fixture(scope="module")
def frames(data, tmp_path_factory):
    """Three target guides of a camera pan: the scene's guide made from
    crops of aero1.jpg that move 8 pixels right and 4 down a frame."""
    d = tmp_path_factory.mktemp("frames")
    for f in (1, 2, 3):
        oiiotool(data / "aerial/aero1.jpg", "--cut", f"128x96+{200 + 8 * f}+{150 + 4 * f}", "--resize", "64x48",
                 "--chsum:weight=.3,.59,.11", "--blur", "3x3", "--flop", "-o", d / f"tgt_{f:04d}.png")
    return d


def sequence_args(scene, frames, *extra):
    return ["stylize", "--style", scene / "style.png", "--guide", scene / "src.png", frames / "tgt_%04d.png",
            "--iters", "3", "--search", "patchmatch", "--quiet", *extra]


@pytest.mark.sanitize
def test_a_sequence_is_its_frames_jobs_and_sends_the_exemplar_to_each_worker_once(texsyn, scene, frames, cluster,
                                                                                   tmp_path):
    run(texsyn, *sequence_args(scene, frames, "--frames", "1..3"), "-o", tmp_path / "e_%04d.png",
        "--nnf", tmp_path / "e_%04d.raw", "--report", tmp_path / "e_%04d.json")
    for f in (1, 2, 3):
        run(texsyn, "stylize", "--style", scene / "style.png", "--guide", scene / "src.png",
            frames / f"tgt_{f:04d}.png", "--iters", "3", "--search", "patchmatch", "--quiet",
            "-o", tmp_path / f"s{f}.png", "--nnf", tmp_path / f"s{f}.raw")
        assert (tmp_path / f"e_{f:04d}.png").read_bytes() == (tmp_path / f"s{f}.png").read_bytes(), f
        assert (tmp_path / f"e_{f:04d}.raw").read_bytes() == (tmp_path / f"s{f}.raw").read_bytes(), f
    assert (tmp_path / "e_0001.png").read_bytes() != (tmp_path / "e_0002.png").read_bytes()
    levels = len(json.loads((tmp_path / "e_0001.json").read_text())["levels"])
    for _ in range(2):
        cluster.worker(1, "--modbus", "0")
    cluster.start()
    run(texsyn, *sequence_args(scene, frames, "--frames", "1..3"), "-o", tmp_path / "c_%04d.png",
        "--nnf", tmp_path / "c_%04d.raw", "--server", cluster.server.addr)
    for f in (1, 2, 3):
        assert (tmp_path / f"c_{f:04d}.png").read_bytes() == (tmp_path / f"e_{f:04d}.png").read_bytes(), f
        assert (tmp_path / f"c_{f:04d}.raw").read_bytes() == (tmp_path / f"e_{f:04d}.raw").read_bytes(), f
    for w in cluster.workers:
        regs = modbus_registers(w.modbus)
        # One source per patchmatch level, whatever the number of frames.
        assert regs["sources_loaded"] == str(levels), regs
        assert int(regs["passes"]) >= 3 * levels * 3, regs


def test_a_sequence_refuses_bad_patterns_and_missing_frames_before_any_work(texsyn, scene, frames, tmp_path):
    def refused(*args, code=2):
        p = run(texsyn, *args, check=False)
        assert p.returncode == code, p.stderr
        return p.stderr

    out = ["-o", tmp_path / "o_%04d.png"]
    bad_style = sequence_args(scene, frames, "--frames", "1..3", *out)
    bad_style[bad_style.index("--style") + 1] = scene / "style_%04d.png"
    assert "the style exemplar is the same for every frame" in refused(*bad_style)
    assert "needs the frame number in its name" in refused(
        *sequence_args(scene, frames, "--frames", "1..3"), "-o", tmp_path / "o.png")
    assert "need A <= B" in refused(*sequence_args(scene, frames, "--frames", "3..1", *out))
    assert "expected A..B" in refused(*sequence_args(scene, frames, "--frames", "1-3", *out))
    assert "'%'" in refused(*sequence_args(scene, frames, "--frames", "1..3"), "-o", tmp_path / "o_%s.png")
    err = refused(*sequence_args(scene, frames, "--frames", "1..4", *out), code=1)
    assert "frame 4: cannot read" in err and "tgt_0004.png" in err
    assert not list(tmp_path.glob("o_*.png")), "a frame ran before the missing one was found"


def test_the_default_search_gives_the_same_bytes_embedded_and_on_a_pool(texsyn, scene, cluster, tmp_path):
    """The default (size) picks each level's mode from the job alone: a
    budget that makes the finest level PatchMatch and the coarser ones exact
    gives the embedded bytes on 3 workers, whose summed speed is not the
    embedded threads'."""
    report = tmp_path / "e.json"
    stylize(texsyn, scene, tmp_path / "e.png", "--nnf", tmp_path / "e.raw", "--report", report, "--budget", "0.005",
            "--embedded")
    search = json.loads(report.read_text())["search"]
    assert search["mode"] == "size" and search["plan_rate"] == 1e9, search
    levels = search["levels"].split(",")
    assert levels[0] == "exact" and levels[-1] == "patchmatch", levels
    cluster.start(3, 1)
    stylize(texsyn, scene, tmp_path / "c.png", "--nnf", tmp_path / "c.raw", "--budget", "0.005", "--report",
            tmp_path / "c.json", "--server", cluster.server.addr)
    assert json.loads((tmp_path / "c.json").read_text())["search"]["levels"] == search["levels"]
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "e.png").read_bytes()
    assert (tmp_path / "c.raw").read_bytes() == (tmp_path / "e.raw").read_bytes()


def test_auto_records_the_modes_it_ran_and_that_list_gives_its_bytes_on_a_cluster(texsyn, scene, cluster, tmp_path):
    """Auto (opt-in) decides from the calibrated speed, so its choice
    depends on the pool; the list its report records runs the same job
    anywhere."""
    report = tmp_path / "a.json"
    stylize(texsyn, scene, tmp_path / "a.png", "--nnf", tmp_path / "a.raw", "--report", report, "--budget", "0.0005",
            "--search", "auto")
    search = json.loads(report.read_text())["search"]
    levels = search["levels"].split(",")
    assert search["mode"] == "auto" and search["plan_rate"] > 0
    assert set(levels) <= {"exact", "patchmatch"} and len(levels) == len(json.loads(report.read_text())["levels"])
    assert search["lossy"] == (["patchmatch"] if "patchmatch" in levels else [])
    cluster.start(2, 1)
    stylize(texsyn, scene, tmp_path / "c.png", "--nnf", tmp_path / "c.raw", "--search", search["levels"],
            "--server", cluster.server.addr)
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "a.png").read_bytes()
    assert (tmp_path / "c.raw").read_bytes() == (tmp_path / "a.raw").read_bytes()
    p = stylize(texsyn, scene, tmp_path / "x.png", "--search", ",".join(levels + ["exact"]), check=False)
    assert p.returncode == 2 and f"--search lists {len(levels) + 1} levels, the job runs {len(levels)}" in p.stderr
    p = stylize(texsyn, scene, tmp_path / "x.png", "--search", "exact,fast", check=False)
    assert p.returncode == 2 and "a list of exact and patchmatch" in p.stderr


def energy_args(scene, image, *extra, tgt=None):
    return ["energy", "--style", scene / "style.png", "--guide", scene / "src.png", tgt or scene / "tgt.png",
            "--image", image, *extra]


@pytest.mark.sanitize
def test_energy_on_a_cluster_prints_what_it_prints_in_process(texsyn, scene, cluster, tmp_path):
    """A stylize output (every patch, and every 2nd pixel) and the exemplar
    as its own stylization, each with and without --json: in-process, with
    --server and with $TEXSYN_SERVER on 2 workers, the same bytes on
    stdout, and both workers searched; --embedded stays in-process whatever
    $TEXSYN_SERVER says; --quiet leaves stderr empty."""
    out = tmp_path / "out.png"
    stylize(texsyn, scene, out)
    cases = [energy_args(scene, out, "--sample", step, *form) for step in ("1", "2") for form in ([], ["--json"])]
    cases.append(energy_args(scene, scene / "style.png", "--json", tgt=scene / "src.png"))

    def score(*where, env=None):
        ps = [run(texsyn, *args, "--quiet", *where, env=env) for args in cases]
        assert all(p.stderr == "" for p in ps), [p.stderr for p in ps]
        return [p.stdout for p in ps]

    embedded = score("--embedded")
    fields = json.loads(embedded[2])
    assert (fields["samples"], fields["step"], fields["patch_size"]) == (768, 2, 5), embedded[2]
    assert embedded[0] == embedded[1] and embedded[2] == embedded[3], embedded  # --json prints what the default does
    assert json.loads(embedded[4])["energy"] < json.loads(embedded[1])["energy"], embedded
    cluster.start(2, 1)
    addr = cluster.server.addr
    before = [w["batches"] for w in cluster.pool()]
    assert score("--server", addr) == embedded
    after = [w["batches"] for w in cluster.pool()]
    assert all(a > b for a, b in zip(after, before)), (before, after)
    assert score(env={"TEXSYN_SERVER": addr}) == embedded
    assert score("--embedded", env={"TEXSYN_SERVER": "127.0.0.1:1"}) == embedded
    p = run(texsyn, *cases[0], "--server", addr)
    assert p.stdout == embedded[0] and re.search(rf"texsyn: energy in [\d.]+s \(job \d+ on {addr} with 2 workers\)", p.stderr), p.stderr


def test_energy_lists_every_mismatch_in_one_error_on_a_cluster_too(texsyn, scene, cluster, tmp_path):
    """A guide source and an image of the wrong size: both in one message,
    exit status 2, in-process and with --server, where nothing is
    submitted."""
    small = tmp_path / "small.png"
    oiiotool(scene / "src.png", "--resize", "32x24", "-o", small)
    cluster.start(2, 1)
    args = ["energy", "--style", scene / "style.png", "--guide", small, scene / "tgt.png", "--image", small]
    for where in (["--embedded"], ["--server", cluster.server.addr]):
        p = run(texsyn, *args, *where, check=False)
        assert p.returncode == 2 and p.stdout == "", (where, p.stderr)
        for line in ("guide 1: its source is 32x24, the style 64x48",
                     "--image is 32x24 with 1 channel; it must have the target guides' size 64x48"):
            assert line in p.stderr, (where, p.stderr)
    assert jobs_listed(cluster.texsyn("status").stdout) == []


def test_a_queued_energy_job_runs_after_a_coordinator_restart(texsyn, scene, cluster, tmp_path):
    """Queued behind a paused queue, the coordinator stopped: the restarted
    one reads the energy job from its spool, runs it, and `texsyn fetch -o`
    writes the JSON an in-process run prints."""
    out = tmp_path / "out.png"
    stylize(texsyn, scene, out)
    want = run(texsyn, *energy_args(scene, out, "--sample", "2", "--json", "--embedded")).stdout
    cluster.start(2, 1, "--modbus", "0", "--modbus-control", "--modbus-allow", "127.0.0.1")
    run(BUILD / "texsyn", "modbus", cluster.server.modbus, "--set", "pause=1")
    job = cluster.texsyn(*energy_args(scene, out, "--sample", "2", "--detach")).stdout.split()[-1]
    assert cluster.texsyn("status", job).stdout.split()[:2] == [job, "held"]
    cluster.server.stop()
    cluster.restart_server()
    cluster.texsyn("watch", job, "--quiet")
    cluster.texsyn("fetch", job, "-o", tmp_path / "energy.json")
    assert (tmp_path / "energy.json").read_text() == want


def test_scale_runs_the_job_at_a_fraction_of_the_inputs_size(texsyn, scene, cluster, tmp_path):
    """--scale 0.5 resamples the exemplar and guides first: the output and
    its NNF are the halved target's size, pointing into the halved
    exemplar, the same bytes embedded and on 2 workers; out of (0, 1] it is
    refused before any work."""
    emb, nnf = tmp_path / "e.png", tmp_path / "e.raw"
    stylize(texsyn, scene, emb, "--scale", "0.5", "--nnf", nnf, "--embedded")
    oiiotool(emb, "-o", tmp_path / "e.ppm")
    w, h, _, _ = read_pnm(tmp_path / "e.ppm")
    assert (w, h) == (32, 24)
    pairs = struct.unpack(f"<{2 * w * h}I", nnf.read_bytes())
    assert max(pairs[0::2]) < 32 and max(pairs[1::2]) < 24
    cluster.start(2, 1)
    stylize(texsyn, scene, tmp_path / "c.png", "--scale", "0.5", "--server", cluster.server.addr)
    assert (tmp_path / "c.png").read_bytes() == emb.read_bytes()
    for bad in ("0", "1.5"):
        p = stylize(texsyn, scene, tmp_path / "x.png", "--scale", bad, "--embedded", check=False)
        assert p.returncode == 2 and f"--scale {bad}: need more than 0, at most 1" in p.stderr, p.stderr
