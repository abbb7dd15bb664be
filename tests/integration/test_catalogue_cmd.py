"""texsyn catalogue (server/cli/catalogue_cmd.c): an aerial catalogue cut
from an orthophoto and its class map. Each class's reference is its
largest clean rectangle (all of the class, --margin pixels from other
classes and the edge), checked against a brute-force search on a small
map; the crops are the photograph's pixels there; the catalogue feeds
texsyn aerial as it is; bad input gets every problem at once and nothing
is written."""
import json
import random

from conftest import BUILD, REPO, run
from pnm import oiiotool, pixels_of

W, H = 56, 40


def write_pnm(path, w, h, ch, data):
    path.write_bytes(f"P{5 if ch == 1 else 6}\n{w} {h}\n255\n".encode() + bytes(data))


def small_scene(d):
    """A 56x40 class map of three classes (rectangles and a disc, one
    stray pixel) and a photograph of random pixels, as PNGs."""
    ids = []
    for y in range(H):
        for x in range(W):
            v = 1
            if x >= 30:
                v = 2
            if (x - 12) ** 2 + (y - 20) ** 2 < 100:
                v = 3
            ids.append(v)
    ids[5 * W + 40] = 1  # a stray pixel of class 1 inside class 2
    rng = random.Random(30)
    write_pnm(d / "map.pgm", W, H, 1, ids)
    write_pnm(d / "photo.ppm", W, H, 3, [rng.randrange(256) for _ in range(W * H * 3)])
    oiiotool(d / "map.pgm", "-o", d / "map.png")
    oiiotool(d / "photo.ppm", "-o", d / "photo.png")
    return ids


def brute_force(ids, cls, margin):
    """The largest rectangle of pixels of class cls at least margin from
    other classes and the edge: (area, x, y, w, h), top-most then
    left-most among equals."""
    clean = [[False] * W for _ in range(H)]
    for y in range(H):
        for x in range(W):
            clean[y][x] = all(0 <= x + dx < W and 0 <= y + dy < H and ids[(y + dy) * W + x + dx] == cls
                              for dy in range(-margin, margin + 1) for dx in range(-margin, margin + 1))
    best = (0, 0, 0, 0, 0)
    for y0 in range(H):
        for x0 in range(W):
            for y1 in range(y0, H):
                if not clean[y1][x0]:
                    break
                for x1 in range(x0, W):
                    if not all(clean[y][x1] for y in range(y0, y1 + 1)):
                        break
                    area = (x1 - x0 + 1) * (y1 - y0 + 1)
                    if area > best[0]:
                        best = (area, x0, y0, x1 - x0 + 1, y1 - y0 + 1)
    return best


def test_each_class_gets_its_largest_clean_rectangle(texsyn, tmp_path):
    ids = small_scene(tmp_path)
    p = run(texsyn, "catalogue", "--photo", tmp_path / "photo.png", "--classes", tmp_path / "map.png", "-o",
            tmp_path / "cat.json", "--margin", "1", "--min-side", "8", "--name", "2=field \"east\"",
            "--structured", "3")
    cat = json.loads((tmp_path / "cat.json").read_text())
    assert [(c["id"], c["name"], c["kind"]) for c in cat["classes"]] == \
        [(1, "class1", "stochastic"), (2, 'field "east"', "stochastic"), (3, "class3", "structured")]
    photo = pixels_of(tmp_path / "photo.png", tmp_path)[3]
    for c in cat["classes"]:
        area, x0, y0, w, h = brute_force(ids, c["id"], 1)
        assert f"class {c['id']} ({c['name']}): {w}x{h} at ({x0}, {y0})" in p.stdout, (p.stdout, area)
        crop = pixels_of(tmp_path / c["reference"], tmp_path)
        assert crop[:2] == (w, h)
        assert crop[3] == b"".join(photo[3 * ((y0 + y) * W + x0):3 * ((y0 + y) * W + x0 + w)] for y in range(h))
    assert cat["classes"][1]["reference"] == "cat-field__east_.png"


def test_the_catalogue_drives_texsyn_aerial(texsyn, tmp_path):
    """A scene's own picture cut into a catalogue, and a scene made from it."""
    run(BUILD / "bench/mkscene", "--size", 256, "--seed", 3, "-o", tmp_path / "scene")
    run("bash", REPO / "bench/aerial_refs.sh", tmp_path)
    classes = tmp_path / "scene-classes.png"
    run(texsyn, "aerial", "--classes", classes, "--catalogue", tmp_path / "catalogue.json", "-o",
        tmp_path / "photo.png", "--quiet")
    run(texsyn, "catalogue", "--photo", tmp_path / "photo.png", "--classes", classes, "-o", tmp_path / "mine.json",
        "--margin", "2", "--min-side", "16")
    run(texsyn, "aerial", "--classes", classes, "--catalogue", tmp_path / "mine.json", "-o", tmp_path / "again.png",
        "--quiet", "--levels", "2")
    assert pixels_of(tmp_path / "again.png", tmp_path)[:3] == (256, 256, 3)


def test_bad_input_gets_every_problem_and_nothing_is_written(texsyn, tmp_path):
    small_scene(tmp_path)
    out = tmp_path / "cat.json"
    p = run(texsyn, "catalogue", "--photo", tmp_path / "photo.png", "--classes", tmp_path / "map.png", "-o", out,
            "--min-side", "20", "--name", "7=x", check=False)
    assert p.returncode == 2
    lines = p.stderr.splitlines()
    assert lines[0] == "texsyn catalogue: --name 7: no pixel of MAP has that value", p.stderr
    assert "class 3 (\"class3\", " in p.stderr and "under --min-side 20: lower --margin (4)" in p.stderr
    assert lines[-1].startswith("texsyn catalogue: nothing written (") and not out.exists()
    assert not list(tmp_path.glob("cat-*.png"))
    oiiotool(tmp_path / "photo.png", "--resize", "28x20", "-o", tmp_path / "half.png")
    p = run(texsyn, "catalogue", "--photo", tmp_path / "half.png", "--classes", tmp_path / "map.png", "-o", out,
            check=False)
    assert p.returncode == 2 and "is 56x40, --photo" in p.stderr and "28x20: need one size" in p.stderr, p.stderr
    p = run(texsyn, "catalogue", "--photo", tmp_path / "photo.png", "--classes", tmp_path / "photo.png", "-o", out,
            check=False)
    assert p.returncode == 2 and "need one 8- or 16-bit channel, not 3" in p.stderr, p.stderr
