"""texsyn segment on texture collages with a known truth, built in the test
from the shared data (collage.py): the brick and grass textures and two
grey crops of aero1.jpg (forest, town); each class trained on one part of
its picture, the collage drawn from other parts as a disk, a triangle and
an L over a grass background. Checked: the accuracy after noise reduction
(at least 0.95; the seed reports 97.7 %), the printed table being the
report's; the same bytes for any thread count, on a 2-worker cluster and
fetched after --detach; 16-bit label values coming back as they are;
bad inputs refused with the file and the problem named.
"""
import json
import re
import subprocess

import pytest

from collage import Source, TextureClass, band, build, disk, ell, oiiotool, read_grey, triangle
from conftest import run


def pair_args(p):
    args = []
    for t, l in zip(p["train"], p["labels"]):
        args += ["--train", t, "--labels", l]
    return args


def segment(texsyn, p, out, *extra, check=True):
    return run(texsyn, "segment", "--quiet", *pair_args(p), "--input", p["input"], "-o", out, *extra, check=check)


@pytest.fixture(scope="module")
def collage(data, tmp_path_factory):
    """256x256: grass (full size) around a brick disk (the texture at 200x200),
    a forest triangle and a town L (aero1.jpg at its own scale)."""
    aero = Source(data / "aerial/aero1.jpg")
    classes = [
        TextureClass("brick", 0, Source(data / "textures/brick.png", "200x200"), "96x96+0+0", "96x96+104+104"),
        TextureClass("grass", 1, Source(data / "textures/grass.png"), "192x192+0+0", "256x256+256+256"),
        TextureClass("forest", 2, aero, "80x56+64+420", "64x56+512+312"),
        TextureClass("town", 3, aero, "128x64+110+105", "128x80+0+110"),
    ]
    layout = [1, (0, disk(0.25, 0.25, 0.18)), (2, triangle((0.68, 0.08), (0.92, 0.08), (0.92, 0.29))),
              (3, ell(0.3, 0.62, 0.79, 0.92, 0.12))]
    return build(classes, layout, 256, tmp_path_factory.mktemp("collage"))


@pytest.fixture(scope="module")
def small(data, tmp_path_factory):
    """80x80, three classes trained on 64x64 crops: for runs repeated many
    ways (threads, a cluster, the sanitizers)."""
    aero = Source(data / "aerial/aero1.jpg")
    classes = [
        TextureClass("brick", 0, Source(data / "textures/brick.png", "200x200"), "64x64+0+0", "64x64+104+104"),
        TextureClass("grass", 1, Source(data / "textures/grass.png", "256x256"), "64x64+0+0", "80x80+128+128"),
        TextureClass("town", 2, aero, "64x64+110+105", "64x64+0+110"),
    ]
    layout = [1, (0, disk(0.3, 0.3, 0.25)), (2, band(0.1, 0.62, 0.9, 0.9))]
    return build(classes, layout, 80, tmp_path_factory.mktemp("small"))


SMALL = ["--levels", "2", "--window", "7", "--denoise", "20"]


def overall_line(table):
    """(before, after) of the table's overall line."""
    m = re.search(r"^overall\s+\d+\s+([\d.]+)\s+([\d.]+)$", table, re.M)
    assert m, table
    return float(m.group(1)), float(m.group(2))


def test_a_collage_is_segmented_with_the_seeds_accuracy(texsyn, collage, tmp_path):
    out, report = tmp_path / "labels.png", tmp_path / "r.json"
    p = segment(texsyn, collage, out, "--truth", collage["truth"], "--denoise", "300", "--report", report)
    r = json.loads(report.read_text())
    acc = r["accuracy"]["overall"]
    assert acc["after"] >= 0.95, p.stdout
    assert acc["after"] > acc["before"], "noise reduction should help on a collage"
    assert overall_line(p.stdout) == (round(acc["before"], 4), round(acc["after"], 4))
    assert r["search"] == {"mode": "exact", "lossy": [], "backend": "local", "simd": r["search"]["simd"],
                           "threads": 2}
    assert r["params"] == {"pairs": 4, "levels": 3, "window": 9, "denoise": 300, "rgb_search": False}
    assert [lv["level"] for lv in r["levels"]] == [2, 1, 0]
    assert r["levels"][2]["size"] == [256, 256] and r["levels"][2]["queries"] == 256 * 256
    for lv in r["levels"]:
        assert len(lv["weight"]) == len(lv["self_rate"]) == 4
    for k in range(4):  # per class, the weights over levels sum to 1
        assert abs(sum(lv["weight"][k] for lv in r["levels"]) - 1) < 1e-5
    w, h, labels = read_grey(out)
    assert (w, h) == (256, 256) and set(labels) <= {0, 1, 2, 3}
    info = subprocess.run(["oiiotool", "--info", out], capture_output=True, text=True, check=True).stdout
    assert "1 channel, uint8" in info


def test_without_truth_nothing_is_printed_or_reported_of_accuracy(texsyn, small, tmp_path):
    report = tmp_path / "r.json"
    p = segment(texsyn, small, tmp_path / "o.png", *SMALL, "--report", report)
    assert p.stdout == ""
    r = json.loads(report.read_text())
    assert "accuracy" not in r and all("accuracy" not in lv for lv in r["levels"])


@pytest.mark.sanitize
def test_same_bytes_for_any_thread_count_on_a_cluster_and_detached(texsyn, small, cluster, tmp_path):
    outs = {}
    for name, where in (("t1", ["--threads", "1"]), ("t3", ["--threads", "3"])):
        p = segment(texsyn, small, tmp_path / f"{name}.png", *SMALL, "--truth", small["truth"], *where)
        outs[name] = p.stdout
    cluster.start(2, 1)
    p = segment(texsyn, small, tmp_path / "c.png", *SMALL, "--truth", small["truth"], "--server",
                cluster.server.addr)
    outs["c"] = p.stdout
    job = segment(texsyn, small, tmp_path / "unused.png", *SMALL, "--truth", small["truth"], "--detach",
                  "--report", tmp_path / "unused.json", "--server", cluster.server.addr).stdout.split()[-1]
    cluster.texsyn("watch", job, "--quiet")
    cluster.texsyn("fetch", job, "-o", tmp_path / "d.png", "--report", tmp_path / "d.json")
    for name in ("t3", "c", "d"):
        assert (tmp_path / f"{name}.png").read_bytes() == (tmp_path / "t1.png").read_bytes(), name
    assert outs["t3"] == outs["t1"] and outs["c"] == outs["t1"]
    before, after = overall_line(outs["t1"])
    assert json.loads((tmp_path / "d.json").read_text())["accuracy"]["overall"]["after"] == pytest.approx(after,
                                                                                                       abs=1e-4)


def test_16_bit_labels_come_back_as_they_are(texsyn, small, tmp_path):
    """Labels 0, 1, 2 written 16-bit become 0, 257, 514: the output is
    16-bit with exactly those values where the 8-bit run has 0, 1, 2."""
    wide = dict(small, labels=[])
    for k, lbl in enumerate(small["labels"]):
        wide["labels"].append(tmp_path / f"l{k}.png")
        oiiotool(lbl, "-d", "uint16", "-o", wide["labels"][-1])
    segment(texsyn, small, tmp_path / "o8.png", *SMALL)
    segment(texsyn, wide, tmp_path / "o16.png", *SMALL)
    info = subprocess.run(["oiiotool", "--info", tmp_path / "o16.png"], capture_output=True, text=True).stdout
    assert "1 channel, uint16" in info
    _, _, v8 = read_grey(tmp_path / "o8.png")
    _, _, v16 = read_grey(tmp_path / "o16.png")
    assert v16 == [257 * v for v in v8]


def errors(texsyn, *args):
    p = run(texsyn, "segment", "--quiet", *args, check=False)
    assert p.returncode == 2, p.stderr
    return p.stderr


def test_a_missing_labels_raster_is_named(texsyn, small, tmp_path):
    t, l = small["train"], small["labels"]
    err = errors(texsyn, "--train", t[0], "--labels", l[0], "--train", t[1], "--input", small["input"],
                 "-o", tmp_path / "o.png")
    assert f"--train {t[1]} has no --labels" in err
    assert not (tmp_path / "o.png").exists()


def test_every_mismatch_is_listed_at_once_with_its_file(texsyn, data, small, tmp_path):
    """A label raster of another size, a colour one, a training image too
    small for the levels: one message, each line naming its file."""
    short = tmp_path / "short.png"
    oiiotool(small["labels"][0], "--cut", "64x60+0+0", "-o", short)
    colour = tmp_path / "colour.png"
    oiiotool(data / "aerial/aero1.jpg", "--cut", "64x64+0+0", "-o", colour)
    tiny, tiny_lbl = tmp_path / "tiny.png", tmp_path / "tiny-lbl.png"
    oiiotool(small["train"][2], "--cut", "30x30+0+0", "-o", tiny)
    oiiotool(small["labels"][2], "--cut", "30x30+0+0", "-o", tiny_lbl)
    t = small["train"]
    err = errors(texsyn, "--train", t[0], "--labels", short, "--train", t[1], "--labels", colour,
                 "--train", tiny, "--labels", tiny_lbl, "--input", small["input"], "-o", tmp_path / "o.png")
    assert f"--labels {short} is 64x60, its training image --train {t[0]} 64x64" in err
    assert f"--labels {colour} has 3 channels" in err
    assert f"--train {tiny} is 30x30: at level 3 of 3 it is 7x7, too small for a 9x9 window" in err


def test_a_truth_with_a_label_no_training_has_is_refused(texsyn, small, tmp_path):
    truth = tmp_path / "truth.png"
    oiiotool(small["truth"], "--addc", 7 / 255, "-d", "uint8", "-o", truth)  # 0, 1, 2 -> 7, 8, 9
    err = errors(texsyn, *pair_args(small), "--input", small["input"], "-o", tmp_path / "o.png", "--truth", truth,
                 *SMALL)
    assert "--truth holds 3 label values no --labels raster has (7, 8, 9); the classes are 0, 1, 2" in err


def read_rgb(path, tmp_path):
    """The RGB triples of an 8-bit colour image, through a binary PPM."""
    ppm = tmp_path / (path.stem + ".ppm")
    subprocess.run(["oiiotool", path, "-o", ppm], check=True)
    data = ppm.read_bytes()
    m = re.match(rb"P6\s+(\d+)\s+(\d+)\s+255\s", data)
    assert m, data[:20]
    w, h = int(m.group(1)), int(m.group(2))
    px = data[m.end():]
    return w, h, [px[3 * i:3 * i + 3] for i in range(w * h)]


@pytest.mark.sanitize
def test_the_palette_gives_each_class_its_own_colour(texsyn, small, tmp_path):
    """--palette draws the labels in colour: one colour per class value,
    different classes apart, and the same bytes on a second run."""
    out, pal, again = tmp_path / "l.png", tmp_path / "p.png", tmp_path / "p2.png"
    segment(texsyn, small, out, *SMALL, "--palette", pal)
    w, h, labels = read_grey(out)
    pw, ph, colours = read_rgb(pal, tmp_path)
    assert (pw, ph) == (w, h)
    of_label = {}
    for v, c in zip(labels, colours):
        assert of_label.setdefault(v, c) == c, f"class {v} drawn in two colours"
    assert len(set(of_label.values())) == len(of_label) >= 3, of_label
    segment(texsyn, small, tmp_path / "l2.png", *SMALL, "--palette", again)
    assert again.read_bytes() == pal.read_bytes()
