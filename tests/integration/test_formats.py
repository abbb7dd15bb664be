"""Formats and mixed pools (issue 13, point 4): cluster jobs from colour,
16-bit, half and float references give the embedded run's exact bytes and
keep the reference's pixel type and channels; a pool of workers on different
SIMD variants and thread counts gives the embedded run's exact bytes too.

The references are cut from the colour aerial photograph (the textures are
grey) and made with oiiotool. Each is resized from a crop twice its size, so
the 16-bit, half and float files hold values between the 8-bit levels, not
8-bit values widened: the output must carry them through untouched.
A TIFF with associated alpha (ExtraSamples=1) once came out labelled
unassociated: its samples were right, their meaning was not (readers
premultiplied them again). test_output_keeps_the_references_alpha_association
holds the fix (common/image_oiio.cpp, ts_out_defaults).
"""
import re
import struct
import subprocess

import pytest

from conftest import run, synth

AERIAL = "aerial/aero1.jpg"
SIZE = (128, 128)
# Water, forest, houses and a road: colour that luminance alone confuses.
CROP = "192x192+400+40"
REF_SIZE = (96, 96)
JOB = ["--levels", "3", "--rgb-search", "--seed", "7"]

# name: (file name, channels, sample type, OpenImageIO's format name). The
# README promises that the output "keeps the reference's pixel type (8/16-bit,
# half, float) and all its channels"; written to the reference's own format,
# the output file holds that type.
FORMATS = {
    "png8": ("png8.png", 3, "uint8", "png"),
    "png16": ("png16.png", 3, "uint16", "png"),
    "tif16": ("tif16.tif", 3, "uint16", "tiff"),
    "exr-half": ("half.exr", 3, "half", "openexr"),
    "exr-float": ("float.exr", 3, "float", "openexr"),
    # Scene-referred values: the bright roofs go over 1.0 (to 1.3), which the
    # 8-bit search planes clamp and the gathered output must not.
    "exr-float-hdr": ("hdr.exr", 3, "float", "openexr"),
    # Alpha (made from green) is not searched on, only copied; PNG alpha is
    # unassociated, TIFF alpha associated as OpenImageIO writes it
    # (ExtraSamples 1), OpenEXR alpha associated by definition.
    "png16-rgba": ("rgba16.png", 4, "uint16", "png"),
    "tif16-rgba": ("rgba16.tif", 4, "uint16", "tiff"),
    "exr-half-rgba": ("rgba-half.exr", 4, "half", "openexr"),
}
# The commands after the crop and resize that write every reference at once
# (-d sets the type of the outputs after it).
MAKE = ["-d", "uint8", "-o", "png8.png", "-d", "uint16", "-o", "png16.png", "-o", "tif16.tif",
        "-d", "half", "-o", "half.exr", "-d", "float", "-o", "float.exr",
        "--dup", "--mulc", "1.25", "-o", "hdr.exr", "--pop",
        "--ch", "R,G,B,A=G", "-d", "uint16", "-o", "rgba16.png", "-o", "rgba16.tif",
        "-d", "half", "-o", "rgba-half.exr"]


def oiiotool(*args, cwd=None):
    p = subprocess.run(["oiiotool", *map(str, args)], capture_output=True, text=True, timeout=120, cwd=cwd)
    assert p.returncode == 0, f"oiiotool {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr}"
    return p.stdout


def dump(*paths, stored=True):
    """{path: ((width, height, channels, sample type, format), {(x, y): samples})}
    from one `oiiotool --dumpdata`: the integer codes for integer types, 9
    decimals for half and float. stored: the samples as the file holds them;
    else as an application that honours the file's alpha association reads
    them (OpenImageIO premultiplies unassociated alpha)."""
    config = ["-iconfig", "oiio:UnassociatedAlpha", "1"] if stored else []
    text = oiiotool("--dumpdata", *(a for p in paths for a in (*config, p)))  # -iconfig: the next input only
    names = {str(p): p for p in paths}
    out, px = {}, None
    for line in text.splitlines():
        m = re.match(r"(\S.*?)\s+:\s+(\d+) x\s+(\d+), (\d+) channel, (\S+) (\S+)$", line)
        if m:
            assert m[1] in names, f"oiiotool --dumpdata named a file it was not given: {line!r}"
            px = {}
            out[names[m[1]]] = ((int(m[2]), int(m[3]), int(m[4]), m[5], m[6]), px)
            continue
        m = re.match(r"\s*Pixel \((\d+), (\d+)\): ([^(]*)", line)
        if m:
            px[int(m[1]), int(m[2])] = tuple(m[3].split())
    assert set(out) == set(paths), f"oiiotool --dumpdata left files out:\n{text[:2000]}"
    return out


class References:
    """Every reference, made by one oiiotool run, and their samples, read
    once each way."""

    def __init__(self, data, where):
        self.dir = where
        w, h = REF_SIZE
        oiiotool(data / AERIAL, "--cut", CROP, "--resize", f"{w}x{h}", *MAKE, cwd=where)
        self._dumps = {}

    def path(self, name):
        return self.dir / FORMATS[name][0]

    def samples(self, name, stored=True):
        if stored not in self._dumps:
            self._dumps[stored] = dump(*(self.path(n) for n in FORMATS), stored=stored)
        return self._dumps[stored][self.path(name)]


@pytest.fixture(scope="module")
def refs(data, tmp_path_factory):
    return References(data, tmp_path_factory.mktemp("references"))


def outputs(tmp_path, ref, label):
    return tmp_path / f"{label}{ref.suffix}", tmp_path / f"{label}.cm"


def remote(cluster, ref, out, cm, size, *extra):
    w, h = size
    cluster.texsyn("synth", "--ref", ref, "-o", out, "--size", f"{w}x{h}", "--quiet", "--copy-map-raw", cm,
                   "--report", f"{out}.json", *extra)


def copy_map(raw, size):
    w, h = size
    assert len(raw) == 8 * w * h, f"copy map of {len(raw)} bytes for {w}x{h}"
    return struct.unpack(f"<{2 * w * h}I", raw)


def assert_gathered(name, out_px, ref_px, cm_path):
    """Every output pixel is the reference pixel the copy map names, all
    channels, sample for sample."""
    w, h = SIZE
    cm = copy_map(cm_path.read_bytes(), SIZE)
    src = {(x, y): (cm[2 * (y * w + x)], cm[2 * (y * w + x) + 1]) for y in range(h) for x in range(w)}
    wrong = [xy for xy in src if out_px[xy] != ref_px[src[xy]]]
    assert not wrong, (f"{name}: {len(wrong)} of {w * h} output pixels are not the reference pixel the copy map "
                       f"names; first at {wrong[0]}: {out_px[wrong[0]]}, reference {src[wrong[0]]}: "
                       f"{ref_px[src[wrong[0]]]}")
    assert len(set(out_px.values())) > 1000, f"{name}: the output is too uniform to test anything"


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.sanitize) if n == "exr-half" else n
                                  for n in FORMATS])
def test_cluster_job_keeps_format_and_matches_embedded(texsyn, refs, cluster, tmp_path, name):
    ref = refs.path(name)
    _, channels, sample, fmt = FORMATS[name]
    ref_info, ref_px = refs.samples(name)
    assert ref_info == (*REF_SIZE, channels, sample, fmt), "oiiotool did not make the reference asked for"
    emb, emb_cm = outputs(tmp_path, ref, "embedded")
    got, got_cm = outputs(tmp_path, ref, "cluster")
    synth(texsyn, ref, emb, SIZE, "--copy-map-raw", emb_cm, *JOB)
    cluster.start(2, 1)
    remote(cluster, ref, got, got_cm, SIZE, *JOB)
    assert all(w["batches"] > 0 for w in cluster.pool()), "a worker never answered"

    # The product's promise: the reference's format, type and channels.
    d = dump(emb, got)
    (emb_info, want_px), (got_info, got_px) = d[emb], d[got]
    assert emb_info == (*SIZE, channels, sample, fmt), f"{name}: the embedded output is not the reference's type"
    assert got_info == (*SIZE, channels, sample, fmt), f"{name}: the cluster output is not the reference's type"

    # The same job, the same bytes; first the same pixels, which say where
    # the bytes differ if they do.
    differ = [xy for xy in want_px if want_px[xy] != got_px.get(xy)]
    assert not differ, (f"{name}: {len(differ)} of {len(want_px)} pixels differ from the embedded run, "
                        f"first at {differ[0]}: {want_px[differ[0]]} != {got_px.get(differ[0])}")
    assert got_cm.read_bytes() == emb_cm.read_bytes(), f"{name}: copy map differs from the embedded run"
    assert got.read_bytes() == emb.read_bytes(), f"{name}: output file differs from the embedded run"

    # No trip through 8 bits, no clamp, alpha neither premultiplied nor
    # divided out: the samples are the reference's, as stored.
    assert_gathered(name, got_px, ref_px, got_cm)


@pytest.mark.parametrize("name", [n for n in FORMATS if FORMATS[n][1] == 4])
def test_output_keeps_the_references_alpha_association(texsyn, refs, tmp_path, name):
    """The samples are copied as stored (the test above); here their meaning:
    read as an application reads them, honouring each file's alpha
    association, every output pixel is still its source pixel. Embedded runs
    suffice: the file is written by the image library both ways."""
    ref = refs.path(name)
    out, cm = outputs(tmp_path, ref, "embedded")
    synth(texsyn, ref, out, SIZE, "--copy-map-raw", cm, *JOB)
    _, ref_px = refs.samples(name, stored=False)
    assert len({px[3] for px in ref_px.values()}) > 100, "alpha too uniform to tell association apart"
    assert_gathered(name, dump(out, stored=False)[out][1], ref_px, cm)


# ---- a pool of mixed SIMD variants and thread counts ----------------------

def simd_variants(texsyn):
    """The variants this CPU runs, lowest first, and the one chosen by default."""
    lines = [l for l in run(texsyn, "simd").stdout.splitlines() if l.strip()]
    names = [l.split()[0] for l in lines]
    best = [l.split()[0] for l in lines if "(selected)" in l]
    assert len(best) == 1, lines
    return names, best[0]


def test_pool_of_mixed_simd_variants_and_threads_matches_embedded(texsyn, data, cluster, tmp_path, monkeypatch):
    monkeypatch.delenv("TEXSYN_SIMD", raising=False)  # the default: the best variant
    names, best = simd_variants(texsyn)
    assert best == names[-1], f"the default variant {best} is not the best of {names}"
    # The lowest, forced; AVX2 forced where the CPU has a better one, else a
    # variant between; the best, unforced. Three distinct kernels.
    middle = "avx2" if "avx2" in names[1:-1] else names[len(names) // 2]
    assert len({names[0], middle, best}) == 3, f"fewer than three SIMD variants here: {names}"
    cluster.worker(1, prefix=("env", f"TEXSYN_SIMD={names[0]}"))
    cluster.worker(2, prefix=("env", f"TEXSYN_SIMD={middle}"))
    cluster.worker(3, prefix=("env", "-u", "TEXSYN_SIMD"))
    cluster.start()
    pool = cluster.pool()
    assert [(w["simd"], w["threads"]) for w in pool] == [(names[0], 1), (middle, 2), (best, 3)], pool

    ref = tmp_path / "aerial.png"
    oiiotool(data / AERIAL, "--cut", "256x192+300+40", "-o", ref)
    differ = []
    for label, extra in (("luma", []), ("rgb", ["--rgb-search"])):
        job = ["--levels", "4", "--seed", "3", *extra]
        emb, emb_cm = outputs(tmp_path, ref, f"embedded-{label}")
        got, got_cm = outputs(tmp_path, ref, f"pool-{label}")
        synth(texsyn, ref, emb, SIZE, "--copy-map-raw", emb_cm, *job)
        before = [w["batches"] for w in cluster.pool()]
        remote(cluster, ref, got, got_cm, SIZE, *job)
        after = cluster.pool()
        assert all(w["batches"] > b for w, b in zip(after, before)), f"{label}: a worker did no work: {after}"
        if got.read_bytes() != emb.read_bytes():
            differ.append(f"{label} image")
        if got_cm.read_bytes() != emb_cm.read_bytes():
            differ.append(f"{label} copy map")
    assert not differ, f"the mixed pool differs from the embedded run: {', '.join(differ)}"
    assert [(w["simd"], w["threads"]) for w in cluster.pool()] == [(names[0], 1), (middle, 2), (best, 3)]
