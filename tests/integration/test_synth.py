"""End-to-end synthesis through the real CLI, on the shared CC0 textures."""
import collections
import struct
import subprocess

import pytest

from conftest import quality, run, synth


def read(path):
    return path.read_bytes()


def test_threads_give_identical_bytes(texsyn, data, tmp_path):
    ref = data / "textures" / "brick.png"
    outs = []
    for t in (1, 2, 3):
        out = tmp_path / f"t{t}.png"
        cmap = tmp_path / f"t{t}.raw"
        synth(texsyn, ref, out, (160, 144), "--levels", "4", "--threads", t, "--copy-map-raw", cmap)
        outs.append((read(out), read(cmap)))
    assert outs[0] == outs[1] == outs[2]
    assert len(outs[0][1]) == 160 * 144 * 8


def test_every_simd_variant_gives_identical_bytes(texsyn, data, tmp_path):
    ref = data / "textures" / "grass.png"
    variants = [l.split()[0] for l in run(texsyn, "simd").stdout.splitlines()]
    assert "scalar" in variants and len(variants) >= 2
    results = {}
    for v in variants:
        out = tmp_path / f"{v}.png"
        rep = synth(texsyn, ref, out, (72, 64), "--levels", "3", "--parity", env={"TEXSYN_SIMD": v})
        assert rep["search"]["simd"] == v
        results[v] = read(out)
    assert len(set(results.values())) == 1, "variants disagree"


def test_forcing_unknown_simd_variant_is_a_clear_error(texsyn, data, tmp_path):
    p = run(texsyn, "synth", "--ref", data / "textures" / "brick.png", "-o", tmp_path / "x.png",
            "--size", "64x64", "--levels", "3", env={"TEXSYN_SIMD": "sse9"}, check=False)
    assert p.returncode != 0
    assert "sse9" in p.stderr


def test_seed_determines_output(texsyn, data, tmp_path):
    ref = data / "textures" / "brick.png"
    a, b, c = (tmp_path / n for n in ("a.png", "b.png", "c.png"))
    synth(texsyn, ref, a, (96, 96), "--levels", "3", "--seed", "5")
    synth(texsyn, ref, b, (96, 96), "--levels", "3", "--seed", "5")
    synth(texsyn, ref, c, (96, 96), "--levels", "3", "--seed", "6")
    assert read(a) == read(b)
    assert read(a) != read(c)


def seam_figures(texsyn, data, tmp_path, texture):
    """Seam and inner errors of a synthesis, and the seam error of a plain
    256x256 crop of the reference (its torus seam is a hard cut)."""
    ref = data / "textures" / f"{texture}.png"
    out = tmp_path / "o.png"
    synth(texsyn, ref, out, (256, 256), "--levels", "4")
    crop = tmp_path / "crop.png"
    run(texsyn, "shuffle", "--ref", ref, "-o", crop, "--size", "256x256", "--block", 256)
    return quality(texsyn, ref, out, samples=2500), quality(texsyn, ref, crop, samples=2500)


@pytest.mark.parametrize("texture", ["brick", "grass"])
def test_output_tiles_far_better_than_a_cut(texsyn, data, tmp_path, texture):
    """The joins of a 2x2 tiling of the output (windows across the torus
    seam) match the reference far better than those of a plain crop."""
    q, cut = seam_figures(texsyn, data, tmp_path, texture)
    assert q["seam_n"] >= 2000 and q["inner_n"] == 2500
    assert cut["inner_mean"] == 0.0  # a crop is the reference itself inside
    assert q["seam_mean"] < 0.7 * cut["seam_mean"], (q, cut)


@pytest.mark.parametrize("texture", ["brick", "grass"])
def test_output_tiles_without_seam(texsyn, data, tmp_path, texture):
    """The issue's criterion: windows across the seam of a 2x2 tiling are no
    worse than inner ones. One image's seam is a few thousand overlapping
    windows along one line, so its mean swings by a factor of 2 between seeds
    either way (grass: 0.5x to 1.7x the inner mean); the criterion holds
    over seeds 1-4 together."""
    ref = data / "textures" / f"{texture}.png"
    seam = inner = 0.0
    for seed in range(1, 5):
        out = tmp_path / f"o{seed}.png"
        synth(texsyn, ref, out, (256, 256), "--levels", "4", "--seed", seed)
        q = quality(texsyn, ref, out, samples=2500)
        seam += q["seam_mean"]
        inner += q["inner_mean"]
    assert seam <= inner * 1.10, (seam, inner)


@pytest.mark.parametrize("texture", ["brick", "grass"])
def test_quality_far_better_than_block_shuffle(texsyn, data, tmp_path, texture):
    ref = data / "textures" / f"{texture}.png"
    out = tmp_path / "o.png"
    synth(texsyn, ref, out, (256, 256), "--levels", "4")
    q = quality(texsyn, ref, out)
    for block in (3, 16):
        shuf = tmp_path / f"shuffle{block}.png"
        run(texsyn, "shuffle", "--ref", ref, "-o", shuf, "--size", "256x256", "--block", block)
        qs = quality(texsyn, ref, shuf)
        assert q["inner_mean"] < 0.75 * qs["inner_mean"], (texture, block, q, qs)


def test_usage_weight_lowers_usage_variance(texsyn, data, tmp_path):
    ref = data / "textures" / "brick.png"
    off = synth(texsyn, ref, tmp_path / "off.png", (192, 192), "--levels", "4")
    on = synth(texsyn, ref, tmp_path / "on.png", (192, 192), "--levels", "4", "--usage-weight", "4")
    assert on["usage"]["variance"] < off["usage"]["variance"]
    assert on["usage"]["mean"] == pytest.approx(off["usage"]["mean"])


def repetition_of(raw, w, h, side=16):
    """The repetition score (server/engines/repetition.h) recomputed from a
    raw copy map: 4-connected pieces of one offset, large from side²
    pixels, a large piece's pixel repeated when another large piece uses
    its source pixel too."""
    xy = struct.unpack(f"<{2 * w * h}I", raw)
    parent = list(range(w * h))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def off(i):
        return xy[2 * i] - i % w, xy[2 * i + 1] - i // w
    for i in range(w * h):
        for j in ((i + 1) if i % w + 1 < w else None, (i + w) if i + w < w * h else None):
            if j is not None and off(i) == off(j):
                a, b = find(i), find(j)
                parent[max(a, b)] = min(a, b)
    roots = [find(i) for i in range(w * h)]
    size = collections.Counter(roots)
    large = [i for i in range(w * h) if size[roots[i]] >= side * side]
    uses = collections.Counter((xy[2 * i], xy[2 * i + 1]) for i in large)
    repeated = sum(1 for i in large if uses[(xy[2 * i], xy[2 * i + 1])] >= 2)
    return {"repeated": repeated, "in_large": len(large), "patches": len(size),
            "large_patches": sum(1 for r, n in size.items() if n >= side * side)}


def test_the_repetition_score_counts_large_pieces_copied_twice(texsyn, data, tmp_path):
    """The report's repetition score is the copy map's (recomputed here),
    and the usage penalty, which spreads the copies, lowers it."""
    ref = data / "textures" / "brick.png"
    scores = {}
    for u in ("0", "4"):
        r = synth(texsyn, ref, tmp_path / f"o{u}.png", (192, 192), "--levels", "4", "--usage-weight", u,
                  "--copy-map-raw", tmp_path / f"c{u}.raw")
        rep = r["repetition"]
        assert rep["side"] == 16
        assert {k: rep[k] for k in ("repeated", "in_large", "patches", "large_patches")} == \
            repetition_of((tmp_path / f"c{u}.raw").read_bytes(), 192, 192)
        assert rep["share"] == pytest.approx(rep["repeated"] / 192 ** 2, abs=1e-6)
        scores[u] = rep["share"]
    assert scores["0"] > 0.05 and scores["4"] < scores["0"] / 2, scores


@pytest.mark.sanitize
def test_small_job_with_all_side_outputs(texsyn, data, tmp_path):
    ref = data / "textures" / "brick.png"
    out = tmp_path / "o.png"
    rep = synth(texsyn, ref, out, (50, 38), "--levels", "2", "--parity", "--usage-weight", "1",
                "--copy-map", tmp_path / "cm.png", "--copy-map-raw", tmp_path / "cm.raw",
                "--usage-map", tmp_path / "u.tif")
    assert rep["search"]["mode"] == "exact" and rep["search"]["lossy"] == []
    assert [l["level"] for l in rep["levels"]] == [1, 0]
    raw = (tmp_path / "cm.raw").read_bytes()
    assert len(raw) == 50 * 38 * 8
    xs = [int.from_bytes(raw[i:i + 4], "little") for i in range(0, len(raw), 8)]
    assert max(xs) < 512
    for f in ("o.png", "cm.png", "u.tif"):
        assert (tmp_path / f).stat().st_size > 0


def oiio_info(path):
    p = subprocess.run(["oiiotool", "--info", "-v", str(path)], capture_output=True, text=True, check=True)
    return p.stdout


@pytest.mark.sanitize
@pytest.mark.parametrize("ext,fmt,expect", [("tif", "uint16", "uint16"), ("exr", "half", "half"),
                                            ("exr", "float", "float")])
def test_pixel_type_is_kept(texsyn, data, tmp_path, ext, fmt, expect):
    """16-bit in gives 16-bit out, half gives half, float gives float."""
    src = tmp_path / f"ref.{ext}"
    subprocess.run(["oiiotool", str(data / "aerial" / "aero1.jpg"), "-d", fmt, "-o", str(src)], check=True)
    out = tmp_path / f"out.{ext}"
    synth(texsyn, src, out, (40, 36), "--levels", "2")
    head = oiio_info(out).splitlines()[1]  # "<file> :   40 x   36, 3 channel, uint16 tiff"
    assert " ".join(head.split(":", 1)[1].split()).startswith(f"40 x 36, 3 channel, {expect}"), head
