"""Partitioned (LBG) search, seed 002 §3.6.5: --lbg is lossy but
deterministic (the same bytes embedded and on a cluster, with faults),
--lbg-exact gives the exact search's bytes, a set queried too seldom for a
codebook to pay is searched exhaustively, the report and the output image
say which search ran, and bad values are refused with the option named.

A codebook pays when its set is queried more than 24 times per partition
(server/engines/mrf.c): these small jobs use few partitions."""
import json
import re
import signal
import struct

import pytest

from conftest import SANITIZED, run, synth

# Small: the partitioned level is level 0 of a 3-level job.
SIZE = (96, 80) if SANITIZED else (128, 112)
BASE = ("--levels", "3", "--parity", "--refine", "1")


def ref_of(data):
    return data / "textures" / "brick.png"


def embedded(texsyn, data, tmp_path, *extra, name="embedded"):
    out, raw = tmp_path / f"{name}.png", tmp_path / f"{name}.raw"
    rep = synth(texsyn, ref_of(data), out, SIZE, *BASE, "--copy-map-raw", raw, *extra)
    return out.read_bytes(), raw.read_bytes(), rep


def png_text(data):
    """The tEXt chunks of a PNG file's bytes, as a dict."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    out, i = {}, 8
    while i < len(data):
        n, kind = struct.unpack(">I4s", data[i:i + 8])
        if kind == b"tEXt":
            key, _, value = data[i + 8:i + 8 + n].partition(b"\0")
            out[key.decode("latin-1")] = value.decode("latin-1")
        i += 12 + n
    return out


def partitioned(rep, level, window=0):
    """Whether the report says the level's set (0 causal, 1 full) was partitioned."""
    lv = next(x for x in rep["levels"] if x["level"] == level)
    return "lbg" in lv and lv["lbg"]["sets"][window]["partitioned"]


@pytest.mark.sanitize
def test_lbg_is_the_same_embedded_and_on_two_workers(texsyn, data, cluster, tmp_path):
    extra = ("--lbg", "4", "--lbg-levels", "0,1", "--usage-weight", "1")
    image, raw, rep = embedded(texsyn, data, tmp_path, *extra)
    exact, exact_raw, _ = embedded(texsyn, data, tmp_path, name="exact")
    assert partitioned(rep, 0)
    assert raw != exact_raw, "partitions changed no block: the search was not partitioned"
    cluster.start(2, 1)
    w, h = SIZE
    out, craw, crep = tmp_path / "remote.png", tmp_path / "remote.raw", tmp_path / "remote.json"
    cluster.texsyn("synth", "--ref", ref_of(data), "-o", out, "--size", f"{w}x{h}", "--quiet", *BASE,
                   "--copy-map-raw", craw, "--report", crep, *extra)
    assert craw.read_bytes() == raw, "the cluster's copy map differs from the embedded run's"
    assert out.read_bytes() == image, "the cluster's image differs from the embedded run's"
    assert all(wk["batches"] > 0 for wk in cluster.pool()), "a worker never answered"
    got = json.loads(crep.read_text())
    assert got["search"]["mode"] == "lbg"
    for a, b in zip(rep["levels"], got["levels"]):  # the same codebooks, and the same vectors compared
        assert ("lbg" in a) == ("lbg" in b)
        if "lbg" not in a:
            continue
        assert a["lbg"]["scanned_fraction"] == b["lbg"]["scanned_fraction"]
        for sa, sb in zip(a["lbg"]["sets"], b["lbg"]["sets"]):
            sa.pop("seconds", None), sb.pop("seconds", None)
            assert sa == sb


def test_lbg_keeps_its_bytes_when_a_worker_dies_and_the_coordinator_restarts(texsyn, data, cluster, tmp_path):
    """The codebooks are a function of the set and the seed: built again
    by a restarted coordinator, and over the survivors' new slicing, they
    give the bytes of the undisturbed embedded run."""
    size = (512, 384)  # long enough to kill a worker, then the coordinator, inside level 0
    extra = ("--lbg", "32", "--lbg-levels", "0,1", "--usage-weight", "1")
    want = tmp_path / "want.png"
    rep = synth(texsyn, ref_of(data), want, size, *extra)
    assert partitioned(rep, 0) and partitioned(rep, 1)
    server_args = ("--calibrate-ms", "50", "--batch-timeout", "0.5", "--checkpoint-interval", "0.05")
    cluster.start(3, 1, *server_args)
    job = cluster.submit(ref_of(data), "--size", "%dx%d" % size, *extra)
    cluster.server.wait_log(rf"job {job}: checkpoint after level 1 ")  # level 0, partitioned, under way
    victim = cluster.workers[1]
    victim.proc.send_signal(signal.SIGKILL)
    cluster.server.wait_log(rf"job {job}: checkpoint inside level 0 ")
    cluster.server.proc.send_signal(signal.SIGKILL)
    cluster.server.proc.wait()
    cluster.server.stop()
    cluster.restart_server(*server_args)
    w = cluster.texsyn("watch", job, "--quiet", check=False, timeout=300)
    log = cluster.server.read_log()
    assert w.returncode == 0, w.stderr + log
    assert re.search(rf"job {job}: resuming inside level 0", log), log
    out = tmp_path / "out.png"
    cluster.texsyn("fetch", job, "-o", out)
    assert out.read_bytes() == want.read_bytes(), "the disturbed job's bytes differ from the embedded run"


def test_lbg_exact_gives_the_exact_bytes(texsyn, data, tmp_path):
    exact, exact_raw, exact_rep = embedded(texsyn, data, tmp_path, name="exact")
    for probe in ("1", "3"):
        image, raw, rep = embedded(texsyn, data, tmp_path, "--lbg", "4", "--lbg-exact", "--lbg-probe", probe,
                                   "--lbg-levels", "all", name=f"pruned{probe}")
        assert partitioned(rep, 0)
        assert image == exact and raw == exact_raw, f"--lbg-exact --lbg-probe {probe} changed the output"
        assert rep["search"]["mode"] == "lbg-exact" and rep["search"]["lossy"] == []
        lbg = rep["search"]["lbg"]
        assert (lbg["partitions"], lbg["probe"], lbg["exact"]) == (4, int(probe), True) and 0 in lbg["levels"]
        assert "texsyn:search" not in png_text(image)
    l0 = next(x for x in rep["levels"] if x["level"] == 0)
    assert 0 < l0["lbg"]["scanned_fraction"] <= 1


def test_report_and_image_say_lossy_lbg(texsyn, data, tmp_path):
    exact, _, exact_rep = embedded(texsyn, data, tmp_path, name="exact")
    assert exact_rep["search"]["mode"] == "exact" and "lbg" not in exact_rep["search"]
    assert all("lbg" not in l for l in exact_rep["levels"])
    assert "texsyn:search" not in png_text(exact)
    image, _, rep = embedded(texsyn, data, tmp_path, "--lbg", "6", "--lbg-probe", "2")
    s = rep["search"]
    assert s["mode"] == "lbg" and s["lossy"] == ["lbg"]
    assert s["lbg"] == {"partitions": 6, "probe": 2, "exact": False, "levels": [0]}
    levels = {l["level"]: l for l in rep["levels"]}
    assert "lbg" not in levels[1] and "lbg" not in levels[2]
    lbg = levels[0]["lbg"]
    assert 0 < lbg["scanned_fraction"] < 1
    causal, full = lbg["sets"]
    assert causal["window"] == "causal" and full["window"] == "full"
    assert causal["queries"] > 24 * 4 * 6 >= full["queries"] > 0  # the seam's few: exhaustive
    assert full == {"window": "full", "queries": full["queries"], "partitioned": False}
    assert 4 <= causal["partitions"] <= 4 * 6  # up to 6 in each parity class
    assert 1 <= causal["sizes"]["min"] <= causal["sizes"]["median"] <= causal["sizes"]["max"]
    assert causal["iterations"] >= 1 and causal["seconds"] >= 0
    text = png_text(image)
    assert "partitions=6 probe=2 levels=0" in text["texsyn:search"]
    assert "lossy LBG search" in text["Description"]  # ImageDescription, as PNG names it


@pytest.mark.sanitize
def test_a_job_too_small_for_a_codebook_runs_exact_and_says_so(texsyn, data, tmp_path):
    exact, exact_raw, _ = embedded(texsyn, data, tmp_path, name="exact")
    image, raw, rep = embedded(texsyn, data, tmp_path, "--lbg", "256", "--lbg-levels", "all")
    assert image == exact and raw == exact_raw
    assert rep["search"]["mode"] == "exact" and rep["search"]["lossy"] == [] and "lbg" not in rep["search"]
    assert all("lbg" not in l for l in rep["levels"])
    assert "texsyn:search" not in png_text(image)


@pytest.mark.sanitize
@pytest.mark.parametrize("args, needle", [
    (["--lbg", "-1"], "--lbg -1: need 0..65536"),
    (["--lbg", "70000"], "--lbg 70000: need 0..65536"),
    (["--lbg", "8", "--lbg-probe", "9"], "--lbg-probe 9: need 1..8"),
    (["--lbg", "8", "--lbg-probe", "0"], "--lbg-probe 0: need 1..65536"),
    (["--lbg-exact"], "need --lbg P"),
    (["--lbg-probe", "2"], "need --lbg P"),
    (["--lbg", "8", "--lbg-levels", "0,x"], "--lbg-levels 0,x: need \"all\" or level numbers"),
    (["--lbg", "8", "--lbg-levels", "3"], "--lbg-levels names level 3, but --levels 3 has levels 0..2"),
])
def test_bad_lbg_values_are_refused(texsyn, data, tmp_path, args, needle):
    w, h = SIZE
    p = run(texsyn, "synth", "--embedded", "--ref", ref_of(data), "-o", tmp_path / "o.png", "--size", f"{w}x{h}",
            *BASE, *args, check=False)
    assert p.returncode == 2, p.stderr
    assert needle in p.stderr
    assert not (tmp_path / "o.png").exists()
