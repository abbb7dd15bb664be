"""More of the seed's method in `texsyn synth`, through the real binaries:
passive usage-variance optimisation (--best-of, §3.7.1), texture mixing
across levels (--ref-fine/--mix-level, §4.3) and the lossy copy-map
shortcut (--copy-accel, §3.6.6). Each gives the same bytes embedded and on
workers; the engine-level details (resumes, the brute-force backend, the
candidate detection) are in tests/unit/test_mrf.c and test_mrf_accel.c."""
import json
import signal
import subprocess
import time

import pytest

from conftest import SANITIZED, run, synth

SIZE = (96, 80) if SANITIZED else (160, 128)
GEOMETRY = ["--levels", "4"]


def brick(data):
    return data / "textures" / "brick.png"


def grass_crop(data, tmp_path, side=96):
    """A small crop of grass: the fine reference of a mixed run."""
    crop = tmp_path / f"grass{side}.png"
    subprocess.run(["oiiotool", str(data / "textures" / "grass.png"), "--cut", f"{side}x{side}+200+150", "-o",
                    str(crop)], check=True)
    return crop


def raw_pairs(path):
    raw = path.read_bytes()
    return [(int.from_bytes(raw[i:i + 4], "little"), int.from_bytes(raw[i + 4:i + 8], "little"))
            for i in range(0, len(raw), 8)]


def remote(cluster, ref, tmp_path, name, *extra, size=SIZE):
    out, raw, report = tmp_path / f"{name}.png", tmp_path / f"{name}.raw", tmp_path / f"{name}.json"
    cluster.texsyn("synth", "--ref", ref, "-o", out, "--size", "%dx%d" % size, "--quiet", "--copy-map-raw", raw,
                   "--report", report, *extra)
    return out.read_bytes(), raw.read_bytes(), json.loads(report.read_text())


def embedded(texsyn, ref, tmp_path, name, *extra, size=SIZE):
    out, raw = tmp_path / f"{name}.png", tmp_path / f"{name}.raw"
    report = synth(texsyn, ref, out, size, "--copy-map-raw", raw, *extra)
    return out.read_bytes(), raw.read_bytes(), report


def grey_pixels(path, tmp_path):
    """(width, height) and the 8-bit pixels of a grey image, through a
    binary PGM that oiiotool writes."""
    pgm = tmp_path / (path.stem + ".pgm")
    subprocess.run(["oiiotool", str(path), "-d", "uint8", "-o", str(pgm)], check=True)
    data = pgm.read_bytes()
    magic, w, h, maxval, rest = data.split(maxsplit=4)
    assert magic == b"P5" and maxval == b"255"
    w, h = int(w), int(h)
    return (w, h), rest[:w * h]


def oiio_attributes(path):
    return subprocess.run(["oiiotool", "--info", "-v", str(path)], capture_output=True, text=True, check=True).stdout


# ---- --best-of -----------------------------------------------------------------

def test_best_of_is_a_plain_run_of_the_chosen_seed(texsyn, data, tmp_path):
    """The report lists every candidate's seed and usage variance; the chosen
    one has the least (ties: the lowest number), the first is --seed, and the
    output is byte for byte a plain run with the chosen seed."""
    img, cmap, rep = embedded(texsyn, brick(data), tmp_path, "best", *GEOMETRY, "--best-of", "5", "--seed", "3")
    b = rep["best_of"]
    runs = b["runs"]
    assert b["candidates"] == 5 and len(runs) == 5 and b["measured_at_level"] == 2
    assert runs[0]["seed"] == 3 and len({r["seed"] for r in runs}) == 5
    variances = [r["usage_variance"] for r in runs]
    assert b["chosen"] == variances.index(min(variances)), runs
    assert b["chosen_seed"] == runs[b["chosen"]]["seed"]
    plain_img, plain_cmap, plain = embedded(texsyn, brick(data), tmp_path, "plain", *GEOMETRY, "--seed",
                                            b["chosen_seed"])
    assert (img, cmap) == (plain_img, plain_cmap)
    assert "best_of" not in plain
    assert rep["usage"] == plain["usage"]


@pytest.mark.sanitize
def test_best_of_same_bytes_on_two_workers(texsyn, data, cluster, tmp_path):
    extra = [*GEOMETRY, "--best-of", "3", "--best-of-levels", "3", "--parity"]
    want = embedded(texsyn, brick(data), tmp_path, "embedded", *extra)
    cluster.start(2, 1)
    got = remote(cluster, brick(data), tmp_path, "remote", *extra)
    assert got[:2] == want[:2]
    assert got[2]["best_of"] == want[2]["best_of"] | {"runs": got[2]["best_of"]["runs"]}
    assert [r["seed"] for r in got[2]["best_of"]["runs"]] == [r["seed"] for r in want[2]["best_of"]["runs"]]
    assert [r["usage_variance"] for r in got[2]["best_of"]["runs"]] == \
        [r["usage_variance"] for r in want[2]["best_of"]["runs"]]


# ---- --ref-fine / --mix-level ------------------------------------------------------

def test_mixing_takes_levels_from_both_references(texsyn, data, tmp_path):
    """Levels >= M are those of a plain run on --ref (the preview at M is the
    same image), the finer ones come from the crop: the report says which,
    the copy map points into the crop, and the output has the crop's pixels."""
    crop = grass_crop(data, tmp_path)
    mix = ["--ref-fine", crop, "--mix-level", "2"]
    prev_mix = tmp_path / "prev_mix.png"
    prev_plain = tmp_path / "prev_plain.png"
    synth(texsyn, brick(data), prev_mix, SIZE, *GEOMETRY, *mix, "--stop-level", "2")
    synth(texsyn, brick(data), prev_plain, SIZE, *GEOMETRY, "--stop-level", "2")
    assert prev_mix.read_bytes() == prev_plain.read_bytes()
    _, cmap, rep = embedded(texsyn, brick(data), tmp_path, "mixed", *GEOMETRY, *mix)
    assert [(lv["level"], lv["from"]) for lv in rep["levels"]] == \
        [(3, "ref"), (2, "ref"), (1, "ref_fine"), (0, "ref_fine")]
    assert rep["levels"][1]["ref"] == [128, 128] and rep["levels"][3]["ref"] == [96, 96]
    assert rep["params"]["mix_level"] == 2
    pairs = raw_pairs(tmp_path / "mixed.raw")
    assert max(x for x, _ in pairs) < 96 and max(y for _, y in pairs) < 96
    (cw, _), crop_px = grey_pixels(crop, tmp_path)
    (w, h), out_px = grey_pixels(tmp_path / "mixed.png", tmp_path)
    assert (w, h) == SIZE
    assert out_px == bytes(crop_px[y * cw + x] for x, y in pairs)


def test_mixing_output_looks_like_the_fine_reference(texsyn, data, tmp_path):
    """A brick layout finished from grass: its local statistics are the
    grass crop's (its exact neighbourhood error against the crop is far
    below that against brick)."""
    crop = grass_crop(data, tmp_path, side=128)
    out = tmp_path / "mixed.png"
    synth(texsyn, brick(data), out, (192, 160), *GEOMETRY, "--ref-fine", crop, "--mix-level", "2")
    q_crop = json.loads(run(texsyn, "quality", "--ref", crop, "--image", out, "--samples", 800).stdout)
    q_brick = json.loads(run(texsyn, "quality", "--ref", brick(data), "--image", out, "--samples", 800).stdout)
    assert q_crop["inner_mean"] < 0.5 * q_brick["inner_mean"], (q_crop, q_brick)


@pytest.mark.sanitize
def test_mixing_same_bytes_on_two_workers(texsyn, data, cluster, tmp_path):
    crop = grass_crop(data, tmp_path)
    extra = [*GEOMETRY, "--ref-fine", crop, "--mix-level", "2", "--usage-weight", "1"]
    want = embedded(texsyn, brick(data), tmp_path, "embedded", *extra)
    cluster.start(2, 1)
    got = remote(cluster, brick(data), tmp_path, "remote", *extra)
    assert got[:2] == want[:2]
    assert [lv["from"] for lv in got[2]["levels"]] == ["ref", "ref", "ref_fine", "ref_fine"]


@pytest.mark.sanitize
def test_mixing_errors_are_clear(texsyn, data, tmp_path):
    crop = grass_crop(data, tmp_path, side=24)
    base = ["synth", "--embedded", "--ref", brick(data), "-o", tmp_path / "x.png", "--size", "96x96", *GEOMETRY]
    p = run(texsyn, *base, "--ref-fine", crop, "--mix-level", "3", check=False)
    assert p.returncode == 2
    assert "--mix-level 3: the --ref-fine image (24x24) is 6x6 at level 2, too small" in p.stderr, p.stderr
    p = run(texsyn, *base, "--ref-fine", crop, check=False)
    assert p.returncode == 2 and "--ref-fine IMG and --mix-level M go together" in p.stderr, p.stderr
    p = run(texsyn, *base, "--ref-fine", crop, "--mix-level", "4", check=False)
    assert p.returncode == 2 and "--mix-level 4: need 1..3" in p.stderr, p.stderr
    p = run(texsyn, *base, "--ref-fine", tmp_path / "missing.png", "--mix-level", "1", check=False)
    assert p.returncode == 1 and "missing.png" in p.stderr, p.stderr


# ---- --copy-accel --------------------------------------------------------------------

ACCEL = ["--levels", "4", "--parity", "--copy-accel"]


def test_copy_accel_is_reported_and_marked_lossy(texsyn, data, tmp_path):
    """With parity (which keeps the coarse regions constant) the levels above
    measure a constancy over 0.95 - once 64 candidates at least have been
    measured - and level 0 (and 1, if enough were measured above it)
    copies; the report says the search was lossy, per level what the
    shortcut did, and the output's metadata says so too (texsyn:search in
    PNG, ImageDescription in TIFF)."""
    _, _, rep = embedded(texsyn, brick(data), tmp_path, "accel", *ACCEL, size=(256, 224))
    assert rep["search"]["mode"] == "copy-map" and rep["search"]["lossy"] == ["copy-map"]
    cm = rep["shortcuts"]["copy_map"]
    assert cm["used"] and cm["lossy"] and cm["kernel"] == 5 and cm["min_constancy"] == 0.95
    roles = {lv["level"]: lv for lv in cm["levels"]}
    assert roles[3]["role"] == "none" and roles[2]["role"] == "measure" and roles[0]["role"] == "copy"
    for lv in cm["levels"]:
        if lv["role"] == "copy":
            assert lv["constancy_above"] >= 0.95 and lv["measured_above"] >= 64, lv
            assert lv["copied"] + lv["measured"] == lv["candidates"] and lv["skipped_share"] > 0.1, lv
        elif lv["role"] == "measure":
            assert lv["copied"] == 0 and lv["measured"] == lv["candidates"], lv
    assert "texsyn:search: \"copy-map (lossy)\"" in oiio_attributes(tmp_path / "accel.png")
    tif = tmp_path / "accel.tif"
    synth(texsyn, brick(data), tif, (256, 224), *ACCEL)
    assert "lossy copy-map shortcut" in oiio_attributes(tif)


def test_copy_accel_changes_few_blocks(texsyn, data, tmp_path):
    """Against the exact run of the same job: a small share of the copy map
    differs (the seed's caveat: it changes the model), and without parity,
    where sources oscillate and regions do not stay constant, the check
    keeps the shortcut off and the result is the exact one."""
    size = (256, 256)
    exact = embedded(texsyn, brick(data), tmp_path, "exact", "--levels", "4", "--parity", size=size)
    accel = embedded(texsyn, brick(data), tmp_path, "accel", *ACCEL, size=size)
    a, e = raw_pairs(tmp_path / "accel.raw"), raw_pairs(tmp_path / "exact.raw")
    differ = sum(x != y for x, y in zip(a, e)) / len(e)
    assert 0 < differ < 0.10, differ
    assert accel[2]["search"]["lossy"] == ["copy-map"] and exact[2]["search"]["lossy"] == []
    no_parity_exact = embedded(texsyn, brick(data), tmp_path, "np_exact", "--levels", "4", size=size)
    no_parity = embedded(texsyn, brick(data), tmp_path, "np_accel", "--levels", "4", "--copy-accel", size=size)
    assert no_parity[2]["search"]["mode"] == "exact" and no_parity[2]["search"]["lossy"] == []
    assert not no_parity[2]["shortcuts"]["copy_map"]["used"]
    assert no_parity[:2] == no_parity_exact[:2]


@pytest.mark.sanitize
def test_copy_accel_same_bytes_on_two_workers(texsyn, data, cluster, tmp_path):
    """Which blocks are copied follows from the copy map above and the
    parameters alone: the workers' replicas learn the copies as placements,
    and the bytes are the embedded run's (a job large enough to copy)."""
    size = (256, 224)
    want = embedded(texsyn, brick(data), tmp_path, "embedded", *ACCEL, size=size)
    cluster.start(2, 1)
    got = remote(cluster, brick(data), tmp_path, "remote", *ACCEL, size=size)
    assert want[2]["search"]["lossy"] == ["copy-map"]
    assert got[:2] == want[:2]
    assert got[2]["shortcuts"] == want[2]["shortcuts"]


def test_copy_accel_job_runs_again_from_its_start_after_a_coordinator_kill(texsyn, data, cluster, tmp_path):
    """A --copy-accel job takes no checkpoints (its choices rest on the copy
    maps of the levels above): killed with -9 in its finest level, the
    coordinator started again runs it from its start, with the same bytes."""
    size = "384x384"
    want = tmp_path / "want.png"
    synth(texsyn, brick(data), want, (384, 384), "--levels", "5", "--parity", "--copy-accel")
    cluster.start(1, 1, "--calibrate-ms", "50", "--checkpoint-interval", "0.05")
    job_id = cluster.submit(brick(data), "--size", size, "--levels", "5", "--parity", "--copy-accel")
    deadline = time.time() + 300
    while "level 5 of 5" not in cluster.texsyn("status", job_id).stdout:
        assert time.time() < deadline and cluster.server.alive(), cluster.server.read_log()
        time.sleep(0.02)
    cluster.server.proc.send_signal(signal.SIGKILL)
    cluster.server.proc.wait()
    first_log = cluster.server.read_log()
    cluster.server.stop()
    assert f"job {job_id}: checkpoint" not in first_log, first_log
    cluster.restart_server("--calibrate-ms", "50")
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    assert w.returncode == 0, w.stderr + cluster.server.read_log()
    assert "resuming" not in cluster.server.read_log()
    got = tmp_path / "got.png"
    cluster.texsyn("fetch", job_id, "-o", got)
    assert got.read_bytes() == want.read_bytes()


@pytest.mark.sanitize
def test_copy_accel_option_errors(texsyn, data, tmp_path):
    base = ["synth", "--embedded", "--ref", brick(data), "-o", tmp_path / "x.png", "--size", "96x96", *GEOMETRY]
    p = run(texsyn, *base, "--copy-accel-kernel", "5", check=False)
    assert p.returncode == 2 and "need --copy-accel" in p.stderr, p.stderr
    p = run(texsyn, *base, "--copy-accel", "--copy-accel-kernel", "4", "--copy-accel-min", "2", check=False)
    assert p.returncode == 2, p.stderr
    assert "--copy-accel-kernel 4: need 0 or odd 1..15" in p.stderr and "--copy-accel-min 2" in p.stderr
    p = run(texsyn, *base, "--best-of", "0", check=False)
    assert p.returncode == 2 and "--best-of 0: need 1..64" in p.stderr, p.stderr
    p = run(texsyn, *base, "--best-of-levels", "2", check=False)
    assert p.returncode == 2 and "--best-of-levels needs --best-of" in p.stderr, p.stderr
